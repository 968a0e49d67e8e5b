"""Error against compiled run time: vi_jax's variational schemes against diffrax's solvers on the
same continuous Euler–Poincaré equations (``vi-jax compare``, ``benchmarks/work_precision.py``; figures in ``vi_jax/plots/work_precision.py``).

All peers are measured in one process: every program is compiled ahead of time (compile time
reported separately), run once as a warm-up, then timed in ``repeats`` interleaved rounds
(median reported). The model and initial state are arguments of every program, never
closed-over constants. Three results:

* work precision: relative final-state error at ``T`` against a Dopri8 reference at the
  tightest tolerance, against median run time;
* long horizon, on a bounded motion: maximum relative energy error, Kelvin–Noether drift and
  group-constraint drift ‖RᵀR − I‖, against run time;
* energy error against time for a representative setting of each peer.
"""

import dataclasses
import json
import math
import os
import statistics
import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .. import continuous
from .._diagnostics import group_constraint_residual
from ..models import HeavyTop, UnderwaterVehicle
from ._tables import format_tables as format_tables
from ._timing import _compiled, _diffrax_run, _setting_text, _vi_jax_run, measure


def _neutral_vehicle():
    default = UnderwaterVehicle()
    return UnderwaterVehicle(buoyancy=default.mass * default.gravity)


SYSTEMS = {
    "vehicle": ("underwater vehicle (seed 000 Tables 1–2, slightly buoyant)", UnderwaterVehicle),
    "vehicle_neutral": ("underwater vehicle at neutral buoyancy (B = mg), Table 2 initial state", _neutral_vehicle),
    "heavy_top": ("heavy top (HeavyTop defaults, spin 6 rad/s)", HeavyTop),
}
REFERENCE_RTOL = 1e-14  # Dopri8, rtol = atol: the tightest tolerance
ACCURACIES = tuple(10.0**-k for k in range(3, 11))  # the work-precision goal's range
GOAL_SPEED_RATIO = 1.5
GOAL_ENERGY_RATIO = 10.0  # issue 12: ≥ 10× smaller energy error at equal run time
ROUND_OFF = 1e-12  # Kelvin–Noether drift / scale counted as round-off


@dataclasses.dataclass(frozen=True)
class Study:
    """Sizes of one study (``QUICK`` and ``FULL`` are the presets).

    ``schemes``: (tau, order) of the DEP scheme, or ("splitting", order);
    ``steps[system][order]`` (DEP) and ``steps[system][("splitting", order)]``: vi_jax step
    counts on [0, T] (RK4 runs at all of them); ``tolerances[solver]``: rtol = atol of the
    adaptive diffrax solvers; ``fields``: diffrax's vector fields (names of
    ``vi_jax.studies._timing.FIELDS``); ``long_*``: the long-horizon run (``long_system`` None:
    none; ``long_schemes``: (tau, order, n_steps); RK4 takes ``long_steps`` steps; ``n_save`` + 1
    saved nodes); ``rk4``: include fixed-step RK4 at vi_jax's step counts.
    """

    systems: tuple
    T: float
    schemes: tuple
    steps: dict
    tolerances: dict
    long_system: str
    long_T: float
    long_steps: int
    long_schemes: tuple
    long_tolerances: dict
    n_save: int
    repeats: int = 5
    fields: tuple = ("vi_jax",)
    rk4: bool = True


_SPLITTINGS = tuple(("splitting", order) for order in (2, 4, 6, 8))
_ALL_SCHEMES = tuple((tau, order) for tau in ("cayley", "exp") for order in (1, 2, 4, 6)) + _SPLITTINGS
# Splitting step counts: h from the composition study's errors (benchmarks/splitting_compositions.py)
# spanning 1e-3 … 1e-10 at T = 50 (the heavy top spins ~6× faster than the vehicle turns).
SPLITTING_STEPS = {  # final-state errors from ~1e-2 down to ~1e-12 per order
    "vehicle": {("splitting", 2): (400, 1600, 6400), ("splitting", 4): (25, 50, 200, 800, 3200),
                ("splitting", 6): (25, 50, 100, 200, 400, 800), ("splitting", 8): (50, 100, 200, 400)},
    "heavy_top": {("splitting", 2): (2000, 8000, 32000), ("splitting", 4): (100, 400, 1600, 6400),
                  ("splitting", 6): (100, 200, 400, 800, 1600), ("splitting", 8): (100, 200, 400, 800, 1600)},
}
# Long horizon (T = 2·10⁴ s): order 8 at h = 0.5 and 0.25, order 6 at 0.25, order 4 at 0.125.
LONG_SPLITTINGS = (("splitting", 8, 40_000), ("splitting", 8, 80_000), ("splitting", 6, 80_000), ("splitting", 4, 160_000))
_DECADES = lambda lo, hi: tuple(10.0**-k for k in range(lo, hi + 1))  # noqa: E731

FULL = Study(
    systems=("vehicle", "heavy_top"),
    T=50.0,
    schemes=_ALL_SCHEMES,
    steps={
        "vehicle": {1: (1000, 4000, 16000), 2: (1000, 4000, 16000), 4: (400, 1600, 6400), 6: (100, 300, 1500),
                    **SPLITTING_STEPS["vehicle"]},
        "heavy_top": {1: (4000, 16000, 64000), 2: (4000, 16000, 64000), 4: (2000, 5000, 16000), 6: (1000, 3000, 12000),
                      **SPLITTING_STEPS["heavy_top"]},
    },
    tolerances={"tsit5": _DECADES(3, 13), "dopri5": _DECADES(3, 13), "dopri8": _DECADES(3, 13), "kvaerno5": _DECADES(3, 8)},
    long_system="vehicle_neutral",
    long_T=20_000.0,
    long_steps=1_000_000,
    long_schemes=(("cayley", 1, 1_000_000), ("cayley", 2, 1_000_000), ("cayley", 4, 1_000_000)) + LONG_SPLITTINGS,
    long_tolerances={"tsit5": (1e-6, 1e-9, 1e-12), "dopri8": (1e-8, 1e-10, 1e-11, 1e-12, 1e-14)},
    n_save=400,
)

QUICK = Study(
    systems=("vehicle",),
    T=50.0,
    schemes=(("cayley", 2), ("cayley", 4), ("splitting", 4), ("splitting", 8)),
    steps={"vehicle": {2: (1000,), 4: (400, 1600), ("splitting", 4): (200, 800), ("splitting", 8): (100, 200)}},
    tolerances={"tsit5": (1e-4, 1e-7, 1e-10), "dopri5": (1e-4, 1e-7, 1e-10), "dopri8": (1e-4, 1e-7, 1e-10, 1e-13), "kvaerno5": (1e-4, 1e-7)},
    long_system="vehicle_neutral",
    long_T=400.0,
    long_steps=20_000,
    long_schemes=(("cayley", 2, 20_000), ("splitting", 8, 800)),
    long_tolerances={"tsit5": (1e-6, 1e-9), "dopri8": (1e-8, 1e-11)},
    n_save=100,
)


def build_runs(study: Study):
    """Every timed configuration of ``study`` (work precision, then long horizon)."""
    runs = []
    for name in study.systems:
        system = SYSTEMS[name][1]()
        x0 = system.initial_state()
        all_steps = set()
        for tau, order in study.schemes:
            for n in study.steps[name][(tau, order) if tau == "splitting" else order]:
                runs.append(_vi_jax_run("work_precision", name, system, x0, tau, order, study.T, n, 1))
                all_steps.add(n)
        for field in study.fields:
            for solver, rtols in study.tolerances.items():
                runs += [_diffrax_run("work_precision", name, system, x0, solver, study.T, r, 1, field) for r in rtols]
        if study.rk4:
            runs += [_diffrax_run("work_precision", name, system, x0, "rk4", study.T, study.T / n, 1) for n in sorted(all_steps)]
    name = study.long_system
    if name is None:
        return runs
    system = SYSTEMS[name][1]()
    x0 = system.initial_state()
    for tau, order, n_steps in study.long_schemes:
        runs.append(_vi_jax_run("long_horizon", name, system, x0, tau, order, study.long_T, n_steps, study.n_save))
    for field in study.fields:
        for solver, rtols in study.long_tolerances.items():
            runs += [_diffrax_run("long_horizon", name, system, x0, solver, study.long_T, r, study.n_save, field) for r in rtols]
    if study.rk4:
        runs.append(_diffrax_run("long_horizon", name, system, x0, "rk4", study.long_T, study.long_T / study.long_steps, study.n_save))
    return runs


# ----------------------------------------------------------------------------- analysis


def _trajectory(run):
    """(y = (g, ξ, q, ν) with a leading node axis, steps taken, succeeded) of a finished run."""
    if run.peer.startswith("vi_jax"):
        if run.section == "work_precision":  # the program returned (g, ξ, q, ν), result
            ys, result = run.output
        else:
            ys, result = (run.output.g, run.output.xi, run.output.q, run.output.nu), run.output.result
        return ys, run.setting["n_steps"], bool(np.all(result == 0))
    ys, n_steps, ok = run.output
    return ys, int(n_steps), bool(ok)


def _relative_error(y, ref):
    """max over the state's parts (R, ω, q, ν) of ‖Δ‖∞ / ‖reference‖∞ at the final node."""
    return max(float(np.max(np.abs(a[-1] - b)) / np.max(np.abs(b))) for a, b in zip(y, ref) if b is not None)


def _invariants(run, system):
    """(t, |E/E₀ − 1|, |I − I₀| / max scale, ‖g − G‖) at the saved nodes."""
    if run.peer.startswith("vi_jax"):
        sol = run.output
        t, energy, kn, scale, g = sol.t, sol.energy, sol.kelvin_noether, sol.kelvin_noether_scale, sol.g
    else:
        ys = jax.tree.map(jnp.asarray, run.output[0])
        t = np.linspace(0.0, float(run.args[2]), ys[0].shape[0])
        energy = continuous.energy(system, ys)
        kn = continuous.kelvin_noether(system, ys)
        scale = continuous.kelvin_noether_scale(system, ys)
        g = ys[0]
    energy, kn = np.asarray(energy), np.asarray(kn)
    kn = kn.reshape(kn.shape[0], -1)
    return (
        np.asarray(t),
        np.abs(energy / energy[0] - 1.0),
        np.max(np.abs(kn - kn[0]), axis=-1) / np.max(np.asarray(scale)),
        np.asarray(group_constraint_residual(system, jnp.asarray(g))),
    )


def _row(run, **values):
    nan_to_none = lambda v: None if isinstance(v, float) and not math.isfinite(v) else v  # noqa: E731
    row = dict(run.setting)
    row.update(
        compile_s=run.compile_s, first_s=run.first_s, median_s=statistics.median(run.samples),
        samples_s=run.samples, **{k: nan_to_none(v) for k, v in values.items()},
    )
    return row


def _time_to_reach(rows, eps):
    """Run time at which one peer's work-precision curve reaches error ``eps``: log-log
    interpolation along its Pareto front (runs sorted by time, each more accurate than all
    cheaper ones); None if no run is that accurate."""
    front = []
    for t, e in sorted((r["median_s"], r["error"]) for r in rows if r["error"] is not None):
        if not front or e < front[-1][1]:
            front.append((t, e))
    if not front or front[-1][1] > eps:
        return None
    if front[0][1] <= eps:
        return front[0][0]
    for (t0, e0), (t1, e1) in zip(front, front[1:]):
        if e1 <= eps:
            w = math.log(eps / e0) / math.log(e1 / e0)
            return math.exp(math.log(t0) + w * math.log(t1 / t0))


def _fastest(peers, prefix, eps):
    times = {p: _time_to_reach(rows, eps) for p, rows in peers.items() if p.startswith(prefix)}
    times = {p: t for p, t in times.items() if t is not None}
    if not times:
        return None, None
    best = min(times, key=times.get)
    return best, times[best]


def _work_precision_goal(peers):
    rows, met = [], True
    for eps in ACCURACIES:
        vi_peer, vi_t = _fastest(peers, "vi_jax", eps)
        dx_peer, dx_t = _fastest(peers, "diffrax", eps)
        ratio = vi_t / dx_t if vi_t is not None and dx_t is not None else None
        met = met and ratio is not None and ratio <= GOAL_SPEED_RATIO
        rows.append(dict(accuracy=eps, vi_jax=vi_peer, vi_jax_s=vi_t, diffrax=dx_peer, diffrax_s=dx_t, ratio=ratio))
    return {"criterion": f"fastest vi_jax ≤ {GOAL_SPEED_RATIO}× fastest diffrax at every accuracy 1e-3 … 1e-10", "met": met, "accuracies": rows}


def _long_horizon_goal(peers):
    diffrax_rows = [r for p, rows in peers.items() if p.startswith("diffrax") for r in rows]
    rows = []
    for peer, row in ((p, r) for p, rows in peers.items() if p.startswith("vi_jax") for r in rows):
        within = [r for r in diffrax_rows if r["median_s"] <= row["median_s"]]
        # Every diffrax run slower: in less time diffrax's error can only be larger than that of
        # its fastest run, so the ratio against that run is a lower bound.
        slower = not within and bool(diffrax_rows)
        within = within or [min(diffrax_rows, key=lambda r: r["median_s"])] if diffrax_rows else []
        best = min((r["energy_error"] for r in within), default=None)
        ratio = best / row["energy_error"] if best is not None else None
        rows.append(dict(
            peer=peer, n_steps=row["n_steps"], median_s=row["median_s"], energy_error=row["energy_error"],
            best_diffrax_energy_error_within_time=best, ratio=ratio, every_diffrax_run_slower=slower,
            energy_met=ratio is not None and ratio >= GOAL_ENERGY_RATIO,
            kelvin_noether_error=row["kelvin_noether_error"], kelvin_noether_met=row["kelvin_noether_error"] <= ROUND_OFF,
        ))
    return {
        "criterion": f"vi_jax energy error ≥ {GOAL_ENERGY_RATIO:g}× smaller than the best diffrax run that takes "
        f"at most as long (if every diffrax run is slower: than its fastest run, a lower bound), and "
        f"Kelvin–Noether drift / scale ≤ {ROUND_OFF:g}",
        "met": any(r["energy_met"] for r in rows) and all(r["kelvin_noether_met"] for r in rows),
        "schemes": rows,
    }


def _reference(name, system, x0, T, cache):
    """Dopri8 at rtol = atol = REFERENCE_RTOL, and its difference from the run at 10× that."""
    finals = []
    for rtol in (REFERENCE_RTOL, 10 * REFERENCE_RTOL):
        run = _diffrax_run("reference", name, system, x0, "dopri8", T, rtol, 1)
        ys, _, ok = jax.device_get(_compiled(cache, run)[0](*run.args))
        if not ok:
            raise RuntimeError(f"reference solve failed for {name}")
        finals.append(ys)
    ref = tuple(None if a is None else a[-1] for a in finals[0])
    return ref, _relative_error(finals[1], ref)


def summarise(study: Study, runs, cache):
    """The JSON-ready result of measured ``runs``."""
    result = {"work_precision": {}, "long_horizon": {}}
    for name in study.systems:
        system = SYSTEMS[name][1]()
        ref, check = _reference(name, system, system.initial_state(), study.T, cache)
        peers = {}
        for run in (r for r in runs if r.section == "work_precision" and r.system == name):
            y, n_steps, ok = _trajectory(run)
            peers.setdefault(run.peer, []).append(_row(
                run, steps_taken=n_steps, succeeded=ok, error=_relative_error(y, ref) if ok else None,
            ))
        result["work_precision"][name] = {
            "system": SYSTEMS[name][0], "T": study.T,
            "error": "max over (R, ω, q, ν) of ‖Δ‖∞ / ‖reference‖∞ at T",
            "reference": {"solver": "diffrax Dopri8, PID", "rtol": REFERENCE_RTOL, "atol": REFERENCE_RTOL,
                          "difference_from_rtol_10x": check},
            "peers": peers, "goal": _work_precision_goal(peers),
        }
    name = study.long_system
    if name is None:
        return result
    system = SYSTEMS[name][1]()
    peers, series = {}, {}
    for run in (r for r in runs if r.section == "long_horizon"):
        _, n_steps, ok = _trajectory(run)
        t, energy, kn, group = _invariants(run, system)
        peers.setdefault(run.peer, []).append(_row(
            run, steps_taken=n_steps, succeeded=ok, energy_error=float(np.max(energy)),
            kelvin_noether_error=float(np.max(kn)), group_drift=float(np.max(group)),
        ))
        series.setdefault(run.peer, []).append((_setting_text(run.setting), t, energy))
    result["long_horizon"] = {
        "system": SYSTEMS[name][0], "T": study.long_T, "rk4_steps": study.long_steps if study.rk4 else None, "saved_nodes": study.n_save + 1,
        "energy_error": "max over saved nodes of |E/E₀ − 1|",
        "kelvin_noether_error": "max over saved nodes of |I − I₀| / max(|μ| + |p||n|)",
        "group_drift": "max over saved nodes of ‖RᵀR − I‖_F",
        "peers": peers, "goal": _long_horizon_goal(peers),
        "energy_vs_time": _representatives(peers, series),
    }
    return result


def _representatives(peers, series):
    """Per peer, the long-horizon run whose time is closest (in log) to the median vi_jax time."""
    vi_times = [r["median_s"] for p, rows in peers.items() if p.startswith("vi_jax") for r in rows]
    target = statistics.median(vi_times) if vi_times else 1.0
    out = {}
    for peer, rows in peers.items():
        i = min(range(len(rows)), key=lambda k: abs(math.log(rows[k]["median_s"] / target)))
        setting, t, energy = series[peer][i]
        out[peer] = {"setting": setting, "t": t[1:].tolist(), "energy_error": energy[1:].tolist()}
    return out


# ----------------------------------------------------------------------------- entry points


def run_study(study: Study, out, *, progress=True, command=None):
    """Measure ``study``, write ``out``/work_precision.json and the three PNGs; return the result."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    cache = {}
    runs = measure(build_runs(study), study.repeats, progress=progress, cache=cache)
    result = summarise(study, runs, cache)
    result["meta"] = {
        "command": command, "repeats": study.repeats, "wall_s": time.perf_counter() - start,
        "jax": jax.__version__, "diffrax": diffrax.__version__, "devices": str(jax.devices()),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "timing": "compiled code only: ahead-of-time compile (compile_s), one warm-up run (first_s), "
        "then repeats in interleaved rounds (samples_s, median_s); diffrax programs take rtol or the "
        "step as an argument, so one compile serves all settings of a solver",
    }
    (out / "work_precision.json").write_text(json.dumps(result, indent=1))
    from ..plots.work_precision import plot_energy_vs_time, plot_long_horizon, plot_work_precision

    plots = [(plot_work_precision, "work_precision.png")] if result["work_precision"] else []
    if result["long_horizon"]:
        plots += [(plot_long_horizon, "long_horizon.png"), (plot_energy_vs_time, "energy_vs_time.png")]
    for plot, name in plots:
        plot(result, out / name)
    return result
