"""Stability study (issue 6): where each scheme stays bounded, where its energy error grows and
where Newton stops converging, on the free rigid body, the heavy top and the underwater vehicle.

* map: step size h against spin rate |ω₀| (default ω₀ direction of each model), |hω| from 1e-2
  to 20 (past π, Cayley's accuracy limit, and 2π, exp's singular set), for vi_jax's Cayley and
  exp schemes of orders 1/2/4/6 and fixed-step diffrax Tsit5, Dopri8, Kvaerno5;
* stiff inertia: principal moments with ratios 1…1e6 (thin rods (1, 1, 1/r), and the general
  (1, √r, r)), added mass 1…1e6 × body mass: largest stable step per method, and the adaptive
  Kvaerno5's step count for the same run;
* near-singular data: ω₀ = 0 and 1e-12, a top exactly upright (Γ ∥ χ), the vehicle with
  n ∥ a and q̇ ∥ a (parallel vectors in the diamond terms); values and gradients;
* long runs (heavy top, Cayley order 2, h = 0.01): energy and Kelvin–Noether error over time
  in float64 and float32 (float32 in a subprocess with JAX_ENABLE_X64=0);
* Newton damping: the map cells where Newton failed, rerun with a backtracking fallback
  (``_stability_newton.py``) and with more iterations.

Every (system, scheme) compiles one vmapped program of fixed batch size and step count; all
sweeps feed it arrays (h, inertia, ω₀, …) and reuse it.

    python benchmarks/stability.py [--quick] [--out benchmarks/results] [--schemes splitting2 …] [--no-long]

The explicit splitting (splitting2/4/6/8) has no Newton solve: its map shows where its energy
error stays accurate or bounded (benchmarks/results/stability_splitting/).
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import jax

if __name__ == "__main__" and "--long-worker" not in sys.argv:
    jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

import vi_jax as vj  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _stability_cases as cases  # noqa: E402
from _stability_newton import patched  # noqa: E402
from _stability_plots import plot_long, plot_maps  # noqa: E402
from _timing import write_json  # noqa: E402

ACCURATE = 1e-3  # max relative energy error of an "accurate" run
BOUNDED = 0.5  # ... of a "bounded" one
OUTCOMES = {0: "ok", 1: "Newton max iterations", 2: "non-finite", 3: "exp singular (|hξ| ≥ π)", 4: "diffrax solve failed"}

QUICK = dict(
    n_steps=400, save_every=4, n_h=10, n_spin=6, ratios=(1.0, 1e2, 1e4, 1e6),
    schemes=("cayley2", "exp2", "Kvaerno5"), long_steps=(100_000,), long_systems=("heavy_top",),
    gradient_systems=("heavy_top",),
)
FULL = dict(
    n_steps=2000, save_every=20, n_h=16, n_spin=10, ratios=(1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6),
    schemes=cases.VI_SCHEMES + cases.SPLITTING_SCHEMES + cases.DIFFRAX_SCHEMES, long_steps=(1_000_000, 10_000_000),
    long_systems=("heavy_top",), gradient_systems=("rigid_body", "heavy_top"),
)
DAMPING_SCHEMES = ("cayley2", "exp2")  # each costs four more compilations where Newton failed
HW_RANGE = (1e-2, 20.0)
SPIN_RANGE = (0.1, 100.0)


class Batches:
    """Feeds runs through one compiled (system, scheme) program in batches of a fixed size."""

    def __init__(self, kind, scheme, cfg):
        self.kind, self.scheme, self.size = kind, scheme, cfg["n_h"] * cfg["n_spin"]
        self.fn = cases.runner(kind, scheme, cfg["n_steps"], cfg["save_every"])
        self.compile_s = None

    def __call__(self, params, h):
        n = len(h)
        outs = []
        for start in range(0, n, self.size):
            idx = np.minimum(np.arange(start, start + self.size), n - 1)  # pad with the last run
            p = {k: jnp.asarray(v[idx]) for k, v in params.items()}
            t = time.perf_counter()
            out = jax.block_until_ready(self.fn(p, jnp.asarray(h[idx])))
            if self.compile_s is None:
                self.compile_s = time.perf_counter() - t
            outs.append(jax.tree.map(lambda x: np.asarray(x)[: min(self.size, n - start)], out))
        return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def broadcast(kind, n, **overrides):
    """n copies of the default params of ``kind`` with per-run ``overrides`` (arrays of length n)."""
    p = {k: np.repeat(v[None], n, axis=0) for k, v in cases.default_params(kind).items()}
    for k, v in overrides.items():
        p[k] = np.asarray(v, float).reshape((n,) + p[k].shape[1:])
    return p


def map_grid(cfg):
    hw = np.logspace(*np.log10(HW_RANGE), cfg["n_h"])
    spins = np.logspace(*np.log10(SPIN_RANGE), cfg["n_spin"])
    S, HW = np.meshgrid(spins, hw, indexing="ij")
    return hw, spins, (HW / S).ravel(), S.ravel()


def sweep_map(run, kind, cfg):
    hw, spins, H, S = map_grid(cfg)
    direction = cases.default_params(kind)["omega"]
    out = run(broadcast(kind, len(H), omega=S[:, None] * direction), H)
    return dict(hw=hw, spin=spins, h=H, **out)


def stiff_families(kind, ratios):
    """(family name, ratio, params overrides) for the stiff-parameter sweep."""
    base = cases.default_params(kind)
    rows = []
    for r in ratios:
        if kind == "underwater_vehicle":
            rows.append(("added mass / body mass", r, dict(added_mass=r * 123.8 * base["added_mass"] / base["added_mass"][0])))
            rows.append(("inertia (1, √r, r)", r, dict(inertia=base["inertia"][0] * np.array([1.0, np.sqrt(r), r]))))
        else:
            rows.append(("thin rod (1, 1, 1/r)", r, dict(inertia=base["inertia"][0] * np.array([1.0, 1.0, 1.0 / r]))))
            rows.append(("inertia (1, √r, r)", r, dict(inertia=base["inertia"][0] * np.array([1.0, np.sqrt(r), r]))))
    return rows


def stiff_h(kind, cfg):
    """Absolute step sizes of the stiff sweep (the models' time scales differ)."""
    top = {"rigid_body": 10.0, "heavy_top": 1.0, "underwater_vehicle": 100.0}[kind]
    return np.logspace(np.log10(top) - 4, np.log10(top), cfg["n_h"])


def sweep_stiff(run, kind, cfg):
    rows = stiff_families(kind, cfg["ratios"])
    hs = stiff_h(kind, cfg)
    n = len(rows) * len(hs)
    p = broadcast(kind, n)
    for i, (_, _, over) in enumerate(rows):
        for k, v in over.items():
            p[k][i * len(hs) : (i + 1) * len(hs)] = v
    out = run(p, np.tile(hs, len(rows)))
    table = []
    for i, (family, r, _) in enumerate(rows):
        sl = slice(i * len(hs), (i + 1) * len(hs))
        sub = {k: v[sl] for k, v in out.items()}
        table.append(dict(family=family, ratio=r, h=hs, **safe_steps(hs, sub)))
    return table


def safe_steps(x, out):
    """Largest x (ascending grid) below which every run is accurate / bounded, and the outcome of
    the first run past the bounded one."""
    ok = out["code"] == 0
    accurate = ok & (out["energy"] <= ACCURATE)
    bounded = ok & (out["energy"] <= BOUNDED)

    def largest(mask):
        k = len(mask) if mask.all() else int(np.argmin(mask))
        return float(x[k - 1]) if k else 0.0, k

    x_acc, _ = largest(accurate)
    x_bnd, k = largest(bounded)
    past = None
    if k < len(x):
        code = int(out["code"][k])
        past = OUTCOMES[code] if code else f"energy error {out['energy'][k]:.2g}"
    return dict(accurate=x_acc, bounded=x_bnd, past=past)


FAST_SPIN = 10.0  # rows where the spin, not gravity or translation, sets the time scale


def map_summary(m):
    """Per spin row: safe |hω| (accurate, bounded) and the first outcome past it; then the
    minimum over the fast rows (|ω₀| ≥ FAST_SPIN) and the safe h of the slowest row."""
    n_spin, n_h = len(m["spin"]), len(m["hw"])
    rows = []
    for i in range(n_spin):
        sl = slice(i * n_h, (i + 1) * n_h)
        rows.append(safe_steps(m["hw"], {k: m[k][sl] for k in ("code", "energy")}))
    codes = {OUTCOMES[c]: int(np.sum(m["code"] == c)) for c in np.unique(m["code"])}
    return dict(
        per_spin=rows,
        accurate_hw=min(r["accurate"] for r, w in zip(rows, m["spin"]) if w >= FAST_SPIN),
        bounded_hw=min(r["bounded"] for r, w in zip(rows, m["spin"]) if w >= FAST_SPIN),
        slow_accurate_h=rows[0]["accurate"] / m["spin"][0],
        slow_bounded_h=rows[0]["bounded"] / m["spin"][0],
        past=[r["past"] for r, w in zip(rows, m["spin"]) if w >= FAST_SPIN],
        outcome_counts=codes,
        max_group_residual_ok=float(np.max(m["group"][m["code"] == 0], initial=0.0)),
    )


def near_singular(run, kind):
    """ω₀ = 0, 1e-12; top upright (sleeping and at rest); vehicle with q̇ ∥ a at h = 0.01."""
    base = cases.default_params(kind)
    labels, overrides = ["omega=0", "omega=1e-12"], [dict(omega=0 * base["omega"]), dict(omega=1e-12 * base["omega"])]
    if kind == "heavy_top":
        for w, name in ((0.0, "upright at rest"), (6.0, "upright sleeping, ω = 6 e3")):
            labels.append(name)
            overrides.append(dict(R0=np.eye(3), omega=np.array([0.0, 0.0, w])))
    if kind == "underwater_vehicle":
        labels.append("omega=0, v0 ∥ a")
        overrides.append(dict(omega=0 * base["omega"], v0=np.array([0.0, 0.0, 0.8])))
    p = broadcast(kind, len(labels))
    for i, over in enumerate(overrides):
        for k, v in over.items():
            p[k][i] = v
    out = run(p, np.full(len(labels), 0.01))
    rows = []
    for i, label in enumerate(labels):
        row = dict(case=label, code=int(out["code"][i]), energy=float(out["energy"][i]),
                   group=float(out["group"][i]), finite=bool(np.all(np.isfinite(out["xi_final"][i]))))
        if kind == "heavy_top" and label.startswith("upright"):
            row["tilt"] = float(np.linalg.norm(out["g_final"][i][2] - np.array([0.0, 0.0, 1.0])))
        rows.append(row)
    return rows


def gradient_check(kind, tau, n_steps=20):
    """Gradients of the final state w.r.t. (ω₀, h) at ω₀ = 0, 1e-12, 1e-6: finite?"""
    base = cases.default_params(kind)
    scales = np.array([0.0, 1e-12, 1e-6])

    def loss(omega, h):
        p = {k: jnp.asarray(v) for k, v in base.items()}
        p["omega"] = omega
        system, x0 = cases.build(kind, p)
        if tau == "splitting":
            sol = vj.simulate(system, x0, h, n_steps, scheme="splitting", order=2)
        else:
            sol = vj.simulate(system, x0, h, n_steps, tau=tau, order=2, throw=False)
        return jnp.sum(sol.g[-1]) + jnp.sum(sol.xi[-1]) + jnp.sum(sol.energy)

    grad = jax.jit(jax.vmap(jax.grad(loss, argnums=(0, 1))))
    g_omega, g_h = grad(jnp.asarray(scales[:, None] * base["omega"]), jnp.full(3, 0.01))
    return [
        dict(omega=float(s), finite=bool(np.all(np.isfinite(go)) and np.isfinite(gh)), grad_h=float(gh))
        for s, go, gh in zip(scales, np.asarray(g_omega), np.asarray(g_h))
    ]


def newton_damping(kind, scheme, m, cfg):
    """Rerun the map cells of (kind, scheme) where Newton failed: plain Newton with 5× the
    iterations, and the damped prototype; also report the plain run at h/2 (step halving)."""
    failed = np.flatnonzero(m["code"] == 1)
    if failed.size == 0:
        return None
    _, _, H, S = map_grid(cfg)
    direction = cases.default_params(kind)["omega"]
    p = broadcast(kind, failed.size, omega=S[failed, None] * direction)
    rows = {}
    for label, kwargs, h in (
        ("plain, 100 iterations", dict(max_newton_iterations=100), H[failed]),
        ("plain, step h/2 (2× the steps)", {}, H[failed] / 2),
    ):
        fn = jax.jit(jax.vmap(lambda p, h: cases.run_vi(kind, scheme, cfg["n_steps"], cfg["save_every"], p, h, **kwargs)))
        rows[label] = jax.tree.map(np.asarray, fn(p, jnp.asarray(h)))
    with patched():
        for label, iters in (("damped, 20 iterations", 20), ("damped, 100 iterations", 100)):
            fn = jax.jit(jax.vmap(lambda p, h: cases.run_vi(
                kind, scheme, cfg["n_steps"], cfg["save_every"], p, h, max_newton_iterations=iters)))
            rows[label] = jax.tree.map(np.asarray, fn(p, jnp.asarray(H[failed])))
    summary = dict(cells=int(failed.size), hw=[float(x) for x in (H * S)[failed]])
    for label, out in rows.items():
        ok = out["code"] == 0
        summary[label] = dict(
            succeeded=int(ok.sum()),
            accurate=int((ok & (out["energy"] <= ACCURATE)).sum()),
            median_energy_error_of_successes=float(np.median(out["energy"][ok])) if ok.any() else None,
            fail_fraction_median=float(np.median(out["fail_fraction"])),
        )
    return summary


# --------------------------------------------------------------------------- long runs


def long_run(kind, n_steps, n_saved=500):
    """Cayley order 2, h = 0.01: |E/E₀ − 1| and |ΔKN|/scale at n_saved nodes, in the current
    precision (JAX_ENABLE_X64 decides)."""
    p = {k: jnp.asarray(v) for k, v in cases.default_params(kind).items()}
    p["omega"] = p["omega"] * {"heavy_top": 6.01, "rigid_body": 1.16, "underwater_vehicle": 0.3}[kind]
    system, x0 = cases.build(kind, p)
    run = jax.jit(lambda: vj.simulate(system, x0, 0.01, n_steps, tau="cayley", order=2,
                                      save_every=n_steps // n_saved, throw=False))
    t = time.perf_counter()
    sol = jax.block_until_ready(run())
    seconds = time.perf_counter() - t
    e = np.asarray(sol.energy, np.float64)
    kn = np.asarray(sol.kelvin_noether, np.float64).reshape(len(e), -1)
    kn_err = np.max(np.abs(kn - kn[0]), axis=-1) / float(sol.kelvin_noether_scale[0])
    return dict(
        dtype=str(sol.energy.dtype), n_steps=n_steps, seconds_incl_compile=seconds,
        steps=(np.arange(len(e)) * (n_steps // n_saved)).tolist(),
        energy_error=(np.abs(e - e[0]) / abs(e[0])).tolist(), kelvin_noether_error=kn_err.tolist(),
        group=float(np.max(np.asarray(vj.group_constraint_residual(system, sol.g)))),
        failures=int(np.sum(np.asarray(sol.result) != 0)),
    )


def long_run_float32(kind, n_steps):
    env = dict(os.environ, JAX_ENABLE_X64="0")
    cmd = [sys.executable, __file__, "--long-worker", kind, str(n_steps)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def growth(run):
    """Slope of log(error envelope) against log(steps) over the second half of the log range."""
    steps = np.asarray(run["steps"][1:], float)
    out = {}
    for key in ("energy_error", "kelvin_noether_error"):
        env = np.maximum.accumulate(np.asarray(run[key][1:]))
        sel = steps >= np.sqrt(steps[-1] * steps[0])
        good = sel & (env > 0)
        slope = np.polyfit(np.log(steps[good]), np.log(env[good]), 1)[0] if good.sum() > 2 else None
        out[key] = dict(final=float(env[-1]), at_1_percent=float(env[len(env) // 100]), loglog_slope=slope)
    return out


# --------------------------------------------------------------------------- main


def tolist(x):
    if isinstance(x, dict):
        return {k: tolist(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [tolist(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def main():
    if sys.argv[1:2] == ["--long-worker"]:
        print(json.dumps(long_run(sys.argv[2], int(sys.argv[3]))))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default="benchmarks/results")
    parser.add_argument("--systems", nargs="+", default=list(cases.SYSTEMS), choices=cases.SYSTEMS)
    parser.add_argument("--schemes", nargs="+", default=None, help="a subset of the preset's schemes (default: all)")
    parser.add_argument("--no-long", action="store_true", help="skip the long runs")
    args = parser.parse_args()
    cfg = dict(QUICK if args.quick else FULL)
    if args.schemes:
        cfg["schemes"] = tuple(args.schemes)
    if args.no_long:
        cfg["long_systems"] = ()
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    results, table, singular, damping = {}, [], {}, {}
    configs = [(kind, scheme) for kind in args.systems for scheme in cfg["schemes"]]
    for kind, scheme in tqdm(configs, desc="stability", unit="config"):
        run = Batches(kind, scheme, cfg)
        m = sweep_map(run, kind, cfg)
        entry = dict(map=m, map_steps=cfg["n_steps"], summary=map_summary(m), stiff=sweep_stiff(run, kind, cfg))
        if scheme in cases.VI_SCHEMES + cases.SPLITTING_SCHEMES:
            singular.setdefault(kind, {})[scheme] = near_singular(run, kind)
            d = newton_damping(kind, scheme, m, cfg) if scheme in DAMPING_SCHEMES else None
            if d:
                damping[f"{kind}/{scheme}"] = d
        entry["compile_and_first_batch_s"] = run.compile_s
        results.setdefault(kind, {})[scheme] = entry
        s = entry["summary"]
        stiff = {f"{r['family']} r={r['ratio']:g}": r["bounded"] for r in entry["stiff"]}
        table.append(dict(system=kind, scheme=scheme, accurate_hw=s["accurate_hw"], bounded_hw=s["bounded_hw"],
                          slow_accurate_h=s["slow_accurate_h"], slow_bounded_h=s["slow_bounded_h"],
                          past=sorted({p for p in s["past"] if p}), stiff_bounded_h=stiff))

    gradients = {}
    for kind in tqdm([k for k in cfg["gradient_systems"] if k in args.systems], desc="gradients"):
        gradients[kind] = {tau: gradient_check(kind, tau) for tau in ("cayley", "exp", "splitting")}

    long_runs = {}
    for kind in [k for k in cfg["long_systems"] if k in args.systems]:
        for n in tqdm(cfg["long_steps"], desc=f"long runs {kind}"):
            long_runs[f"{kind} float64 {n:.0e}"] = long_run(kind, n)
            long_runs[f"{kind} float32 {n:.0e}"] = long_run_float32(kind, n)
    growth_table = {label: growth(run) for label, run in long_runs.items()}

    print(f"\nlargest |hω| with max energy error ≤ {ACCURATE:g} / bounded (≤ {BOUNDED:g}), min over |ω₀| ≥ {FAST_SPIN:g};"
          f" largest h at |ω₀| = {SPIN_RANGE[0]:g}")
    print(f"{'system':20s} {'scheme':9s} {'acc |hω|':>9s} {'bnd |hω|':>9s} {'acc h':>8s} {'bnd h':>8s}  past the bounded step")
    for row in table:
        print(f"{row['system']:20s} {row['scheme']:9s} {row['accurate_hw']:9.3g} {row['bounded_hw']:9.3g}"
              f" {row['slow_accurate_h']:8.3g} {row['slow_bounded_h']:8.3g}  {', '.join(row['past'])}")
    print("\nstiff parameters: largest bounded h")
    for row in table:
        print(f"{row['system']:20s} {row['scheme']:9s} " + ", ".join(f"{k}: {v:.3g}" for k, v in row["stiff_bounded_h"].items()))
    print("\nlong runs (envelope of the error; slope of log error vs log steps)")
    for label, g in growth_table.items():
        e, k = g["energy_error"], g["kelvin_noether_error"]
        print(f"{label:34s} energy {e['final']:.2e} (slope {e['loglog_slope'] or float('nan'):.2f})"
              f"  KN {k['final']:.2e} (slope {k['loglog_slope'] or float('nan'):.2f})")
    print("\nNewton damping on the cells where plain Newton failed:")
    for key, d in damping.items():
        print(f"{key}: {d['cells']} cells; " + "; ".join(
            f"{label}: {v['succeeded']} ok / {v['accurate']} accurate" for label, v in d.items() if isinstance(v, dict)))

    payload = dict(
        mode="quick" if args.quick else "full", config=cfg, accurate=ACCURATE, bounded=BOUNDED,
        outcomes=OUTCOMES, table=table, results=results, near_singular=singular, gradients=gradients,
        long_runs=long_runs, growth=growth_table, newton_damping=damping,
        plots=plot_maps(results, out_dir) + ([plot_long(long_runs, out_dir)] if long_runs else []),
    )
    write_json(out_dir / "stability.json", tolist(payload))


if __name__ == "__main__":
    main()
