"""Which composition for the explicit splitting of separable scenes (vi_jax/discrete/_splitting.py):
final-state error against run time on the underwater vehicle (T = 50, Table 1/2 defaults), for
every candidate of ``METHODS`` at orders 2 to 8, and for the order of the pieces
(``arrangement``) at orders 2, 6 and 8.

Error: max |·| over the entries of R(T) and q(T) against Dopri8 at rtol = atol = 1e-14 (checked
against the finest order-8 splitting run). Cost: µs per step of ``splitting_run`` (final node
only, model and initial data as jit arguments), median of round-robin repeats, all in one
process. A stage has the same flows for every method of one arrangement, so a run costs its
number of stages for an error (interpolated in log–log between the measured step sizes) times
the arrangement's median µs per stage: candidates are ranked by that, which the machine's load
disturbs less than single timings.

    python benchmarks/splitting_compositions.py [--fast-loops] [--out benchmarks/results/splitting_compositions.json]

``--fast-loops`` calls ``vi_jax.enable_fast_cpu_loops()`` first (the XLA:CPU loop option).
"""

import argparse

import numpy as np

from _timing import parse_args_with_fast_loops, time_compiled, write_json


def parse():
    parser = argparse.ArgumentParser()
    parser.add_argument("--T", type=float, default=50.0)
    parser.add_argument("--cost-steps", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=None)
    return parse_args_with_fast_loops(parser)


ARGS = parse()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax import continuous  # noqa: E402
from vi_jax.discrete import _splitting as S  # noqa: E402
from vi_jax.discrete._splitting_pieces import separable_parts  # noqa: E402


STEP_COUNTS = {  # per order: T/h, spanning errors ~1e-2 … 1e-11
    2: (400, 800, 1600, 3200, 6400),
    4: (50, 100, 200, 400, 800, 1600, 3200),
    6: (25, 50, 100, 200, 400, 800, 1600),
    8: (25, 50, 100, 200, 400, 800),
}
ARRANGEMENTS = {  # outermost piece first; "R": the rotation axes 0, 1, 2
    "V R T": ("V", "R", "T"),
    "V T R": ("V", "T", "R"),
    "T R V": ("T", "R", "V"),
    "R V T": ("R", "V", "T"),
    "V 1 2 0 T": ("V", 1, 2, 0, "T"),
}
DEFAULT = "V R T"  # for the cross-check of the reference
TARGETS = (1e-4, 1e-6, 1e-8, 1e-10)


def final_errors(model, x0, method, arrangement, g_ref, q_ref, counts):
    """Final-state errors for each step count, one compiled loop (step count dynamic)."""
    order = S.METHODS[method][0]

    @jax.jit
    def run(m, x, h, n):
        parts = separable_parts(m)
        state = S.splitting_initial_state(m, x)
        step = lambda _, s: S.splitting_step(parts, h, s, order, method=method, arrangement=arrangement)  # noqa: E731
        return jax.lax.fori_loop(0, n, step, state)

    errors = []
    for n in counts:
        s = run(model, x0, ARGS.T / n, n)
        errors.append(max(float(jnp.max(jnp.abs(s.g - g_ref))), float(jnp.max(jnp.abs(s.q - q_ref)))))
    return errors


def step_costs(model, x0, keys):
    """µs per step of ``splitting_run`` for each (method, arrangement): all compiled first, then
    timed round-robin (median of ``--repeats`` rounds), so that a drifting machine load biases no
    candidate against another."""
    n = ARGS.cost_steps
    h = ARGS.T / 800
    fns, compile_s = {}, {}
    for method, arr_name in keys:
        order = S.METHODS[method][0]
        fns[method, arr_name] = jax.jit(
            lambda m, x, method=method, order=order, arr=ARRANGEMENTS[arr_name]:
            S.splitting_run(m, x, h, n, order, save_every=n, method=method, arrangement=arr).g
        )
        compile_s[method, arr_name] = time_compiled(fns[method, arr_name], model, x0, repeats=1)[0]
    samples = {key: [] for key in keys}
    for _ in range(ARGS.repeats):
        for key in keys:
            samples[key].append(time_compiled(fns[key], model, x0, repeats=1)[1])
    return {key: (compile_s[key], 1e6 * float(np.median(samples[key])) / n) for key in keys}


def to_reach(hs, errors, cost_per_step, target):
    """Cost for T (cost_per_step · T/h) at the error ``target``, log–log interpolation between the
    measured step sizes (None outside them)."""
    cost = np.asarray([cost_per_step * ARGS.T / h for h in hs])
    e = np.asarray(errors)
    for k in range(len(e) - 1):
        if (e[k] - target) * (e[k + 1] - target) <= 0 and e[k] != e[k + 1]:
            w = np.log(target / e[k]) / np.log(e[k + 1] / e[k])
            return float(np.exp(np.log(cost[k]) + w * np.log(cost[k + 1] / cost[k])))
    return None


def main():
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    ref = continuous.solve(model, x0, ARGS.T, rtol=1e-14, atol=1e-14, dt0=1e-3, max_steps=10_000_000)
    g_ref, q_ref = ref.ys[0][-1], ref.ys[2][-1]

    candidates = [(m, a) for m in S.METHODS for a in ("V R T", "V T R", "T R V")]
    candidates += [(m, a) for m in ("strang", "blanes_moan10", "kahan_li17") for a in ("R V T", "V 1 2 0 T")]
    errors = {}
    for method, arr_name in candidates:
        counts = STEP_COUNTS[S.METHODS[method][0]]
        errors[method, arr_name] = final_errors(model, x0, method, ARRANGEMENTS[arr_name], g_ref, q_ref, counts)
        print(f"{method} [{arr_name}] errors " + " ".join(f"{e:.1e}" for e in errors[method, arr_name]), flush=True)
    costs = step_costs(model, x0, candidates)
    rows = {}
    for method, arr_name in candidates:
        order = S.METHODS[method][0]
        hs = [ARGS.T / n for n in STEP_COUNTS[order]]
        compile_s, us = costs[method, arr_name]
        errs = errors[method, arr_name]
        stages = len(S.METHODS[method][1]) // 2
        rows[f"{method} [{arr_name}]"] = dict(
            method=method, order=order, source=S.METHODS[method][2], arrangement=arr_name, stages=stages,
            h=hs, error=errs, us_per_step=us, us_per_stage=us / stages, compile_s=compile_s,
            stages_to_reach={f"{t:.0e}": to_reach(hs, errs, stages, t) for t in TARGETS},
            ms_to_reach={f"{t:.0e}": to_reach(hs, errs, us / 1e3, t) for t in TARGETS},
        )
    # A stage has the same flows for every method of one arrangement (which ones, and how many
    # potential kicks, depend on the arrangement), so a run costs its number of stages times the
    # arrangement's cost of a stage: the median over its methods, which the machine's load
    # disturbs less than any single timing.
    per_stage = {a: float(np.median([r["us_per_stage"] for r in rows.values() if r["arrangement"] == a])) for a in ARRANGEMENTS}
    for r in rows.values():
        r["ms_to_reach_at_median_stage_cost"] = {
            t: None if s is None else s * per_stage[r["arrangement"]] / 1e3 for t, s in r["stages_to_reach"].items()
        }

    # The finest order-8 run against the reference: how far down the reference can be trusted.
    finest = final_errors(model, x0, "kahan_li17", ARRANGEMENTS[DEFAULT], g_ref, q_ref, (3200,))[0]

    print(f"\nvehicle, T = {ARGS.T:g}: run time [ms] to reach a final-state error at the arrangement's median "
          f"µs per stage (loop option: {ARGS.fast_loops}); measured µs per step and per stage")
    print(f"{'method [arrangement]':34s} {'µs/step':>8s} {'µs/stage':>8s} " + " ".join(f"{t:>8.0e}" for t in TARGETS))
    for key, r in rows.items():
        ms = r["ms_to_reach_at_median_stage_cost"]
        cells = " ".join(f"{ms[f'{t:.0e}']:8.3f}" if ms[f"{t:.0e}"] else f"{'—':>8s}" for t in TARGETS)
        print(f"{key:34s} {r['us_per_step']:8.2f} {r['us_per_stage']:8.2f} {cells}")
    print("median µs per stage by arrangement: " + ", ".join(f"{a} {c:.2f}" for a, c in per_stage.items()))
    print(f"kahan_li17 at h = {ARGS.T / 3200:g} against the Dopri8 reference: {finest:.2e}")
    best = {}
    for order in sorted({r["order"] for r in rows.values()}):
        group = {k: r["ms_to_reach_at_median_stage_cost"] for k, r in rows.items() if r["order"] == order}
        common = [f"{t:.0e}" for t in TARGETS if all(ms[f"{t:.0e}"] for ms in group.values())]
        score = {k: float(np.exp(np.mean([np.log(ms[t]) for t in common]))) for k, ms in group.items()}
        best[order] = min(score, key=score.get)
        print(f"order {order}: most efficient {best[order]} over {common}: ms = "
              + ", ".join(f"{t}: {group[best[order]][t]:.3f}" for t in common))
    out = ARGS.out or f"benchmarks/results/splitting_compositions{'_fast_loops' if ARGS.fast_loops else ''}.json"
    write_json(out, dict(
        T=ARGS.T, fast_loops=ARGS.fast_loops, cost_steps=ARGS.cost_steps, reference="Dopri8 rtol=atol=1e-14",
        finest_order8_vs_reference=finest, devices=str(jax.devices()), median_us_per_stage=per_stage,
        most_efficient=best, rows=rows,
    ))


if __name__ == "__main__":
    main()
