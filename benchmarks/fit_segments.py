"""The fit's segments on the CPU, one after another (``lax.map``, vi_jax's plan) against one
``vmap`` over them (the plan before): the choice in
:func:`vi_jax.fitting._shooting.segment_sweeps`.

    python benchmarks/fit_segments.py [--rounds 3] [--fast-loops]

Per plan and fit problem, in a fresh process (nothing compiled before), the fit's two programs of
residuals and Jacobian at the first guess (its multiple-shooting stages, 64 segments, and its
single-shooting stage): the first call (trace, compile and run: what a first fit waits for) and
the median of 7 further calls. The problems: ``benchmarks/fit_time.py``'s (200 samples over
60 s, order 1) and the README's ``docs/telemetry_example.csv`` (150 samples over 60 s, order 2),
both with h = 0.05. The plans' processes alternate, ``--rounds`` times.
"""

import argparse
import statistics
import sys

from _timing import fresh_process_runs, parse_args_with_fast_loops, write_config_json

PLANS = ("lax.map (now)", "vmap (before)")
PROBLEMS = {"fit_time.py, order 1": 1, "telemetry_example.csv, order 2": 2}

CHILD = r"""
import json, sys, time, statistics
sys.path.insert(0, "benchmarks")
plan, order, fast = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
import vi_jax as vj
if fast:
    vj.enable_fast_cpu_loops()
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from vi_jax.fitting import _fit, _shooting
from vi_jax.fitting._parametrisation import FreeParameters, Parametrisation

def vmapped_sweeps(theta_free, states, R_ref, model_of, layout, tau, order):
    n_free = theta_free.size
    def one_segment(s, Rr):
        z = jnp.concatenate([theta_free, s])
        return jax.jacfwd(_shooting._segment_nodes, has_aux=True)(z, Rr, model_of, layout, tau, order, n_free)
    return jax.vmap(one_segment)(states, R_ref)

if plan == "vmap (before)":
    _shooting.segment_sweeps = vmapped_sweeps
if order == 1:
    from fit_time import fit_problem
    _, _, data, guess = fit_problem()
else:
    from vi_jax.fitting._csv import read_telemetry
    data = read_telemetry("docs/telemetry_example.csv", sigma={"position": 0.01, "attitude": 0.01})
    guess = vj.models.UnderwaterVehicle(added_mass=(80.0, 55.0, 90.0), inertia=(4.5, 6.5, 5.0), buoyancy_offset=(0.003, -0.004, -0.012))
t = np.asarray(data.t)
model_of = FreeParameters(Parametrisation(guess), guess, _fit.DEFAULT_FREE)
n_steps = int(np.ceil((t[-1] - t[0]) / _fit.DEFAULT_H - 1e-9))
out = {}
for segments in (_fit.MAX_SEGMENTS, 1):
    layout = _shooting.Layout(t, t[0], _fit.DEFAULT_H, segments, n_steps)
    states, R_ref = _fit.estimate_states(data, layout.start_times(), _fit._identity_fallback(segments))
    args = (model_of.initial(), jnp.asarray(states), jnp.asarray(R_ref), model_of, layout, _shooting.samples_of(data), jnp.asarray(1.0), "squared", "cayley", order)
    start = time.perf_counter()
    r, J, ok, _ = jax.block_until_ready(_shooting.residuals_and_jacobian(*args))
    first = time.perf_counter() - start
    runs = []
    for _ in range(7):
        start = time.perf_counter()
        jax.block_until_ready(_shooting.residuals_and_jacobian(*args))
        runs.append(time.perf_counter() - start)
    out[str(segments)] = {"first_s": first, "run_s": statistics.median(runs), "ok": bool(ok), "J_norm": float(jnp.linalg.norm(J))}
print("JSON " + json.dumps(out))
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3, help="fresh processes per plan and problem")
    args = parse_args_with_fast_loops(parser)
    cases = {(plan, problem): (plan, order, int(args.fast_loops)) for problem, order in PROBLEMS.items() for plan in PLANS}
    runs = fresh_process_runs(CHILD, cases, args.rounds)
    rows = []
    for problem in PROBLEMS:
        now, before = (runs[(plan, problem)] for plan in PLANS)
        for segments in ("64", "1"):
            row = {"problem": problem, "segments": int(segments)}
            for plan, plan_runs in zip(PLANS, (now, before)):
                row[plan] = {key: [r[segments][key] for r in plan_runs] for key in ("first_s", "run_s", "J_norm")}
            # Each round's two processes ran one after the other: their ratio shares the machine's load.
            row["first_ratio_per_round"] = [a["first_s"] / b["first_s"] for a, b in zip((r[segments] for r in now), (r[segments] for r in before))]
            row["run_ratio_per_round"] = [a["run_s"] / b["run_s"] for a, b in zip((r[segments] for r in now), (r[segments] for r in before))]
            row["J_relative_difference"] = abs(now[0][segments]["J_norm"] / before[0][segments]["J_norm"] - 1)
            rows.append(row)
            first = [f"{x:.2f}" for x in row["first_ratio_per_round"]]
            run = [f"{x:.2f}" for x in row["run_ratio_per_round"]]
            print(f"{problem:32s} {segments:>2s} segment(s): first call {statistics.median(row[PLANS[0]]['first_s']):5.1f} s against "
                  f"{statistics.median(row[PLANS[1]]['first_s']):5.1f} s (x {', '.join(first)}); run x {', '.join(run)}", flush=True)
    write_config_json("fit_segments", args.fast_loops, command=" ".join(["python", *sys.argv]), rounds=args.rounds, rows=rows)


if __name__ == "__main__":
    main()
