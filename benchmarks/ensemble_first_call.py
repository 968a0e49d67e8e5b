"""The first concrete call of ``vj.ensemble`` through the generated step (64 members, 1000
steps, final node saved, Cayley, order 2): with the optimistic plan (a program without Newton's
full iterations first, the full program only where some member needed them:
``vi_jax.engine._ensemble.optimistically``) and with the full program alone. Each call runs in a fresh
process (nothing compiled before it), the two plans alternately, three times each; the median
first call (trace + compile + run), its backend compile time (JAX's monitoring events) and the
second call are reported. The heavy top at h = 0.02 needs the full iterations (a run that pays
both programs).

    python benchmarks/ensemble_first_call.py [--fast-loops]
"""

from _timing import fast_loops_from_argv, fresh_process_runs, medians, write_config_json

CASES = [("UnderwaterVehicle", 0.01), ("HeavyTop", 0.01), ("HeavyTop", 0.02)]
PLANS = ("optimistic", "full program only")
MEMBERS, STEPS, ORDER, REPEATS = 64, 1000, 2, 3

CHILD = """
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
from jax._src import monitoring
compile_s = []
monitoring.register_event_duration_secs_listener(
    lambda event, duration, **_: compile_s.append(duration) if event.endswith("backend_compile_duration") else None)
import numpy as np
import vi_jax as vj
from vi_jax.engine import _ensemble
scene, h, plan, members, steps, order = sys.argv[1], float(sys.argv[2]), sys.argv[3], *map(int, sys.argv[4:7])
if plan == "full program only":
    _ensemble.optimistically = lambda program, max_iterations, failed: program(max_iterations, False)
model = getattr(vj.models, scene)()
x0 = model.initial_state()
states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(members, 3)))
compile_s.clear()
times = []
for _ in range(2):
    start = time.perf_counter()
    sol = vj.ensemble(model, states, h, steps, order=order, save_every=steps)
    jax.block_until_ready(sol.q)
    times.append(time.perf_counter() - start)
fell_back = float(np.mean(np.asarray(sol.newton_iterations[:, 1:]) > 3))
print("JSON " + json.dumps(dict(first_call_s=times[0], second_call_s=times[1], backend_compile_s=sum(compile_s), fell_back=fell_back)))
"""


def main():
    fast_loops = fast_loops_from_argv()
    cases = {(scene, h, plan): [scene, h, plan, MEMBERS, STEPS, ORDER] for scene, h in CASES for plan in PLANS}
    rows = []
    for (scene, h, plan), runs in fresh_process_runs(CHILD, cases, REPEATS).items():
        row = dict(scene=scene, h=h, plan=plan, members=MEMBERS, steps=STEPS, order=ORDER,
                   fell_back=runs[0]["fell_back"], repeats=REPEATS)
        row.update(medians(runs, ("first_call_s", "second_call_s", "backend_compile_s")))
        rows.append(row)
        print(f"{scene:17s} h = {h:4}  {plan:18s}: first call {row['first_call_s']:5.2f} s (backend compile "
              f"{row['backend_compile_s']:5.2f} s), second {row['second_call_s']:.3f} s; nodes whose steps "
              f"needed the full iterations: {row['fell_back']:.0%}", flush=True)
    write_config_json("ensemble_first_call", fast_loops, rows=rows)


if __name__ == "__main__":
    main()
