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

import json
import statistics
import subprocess
import sys

from _timing import fast_loops_from_argv, write_config_json

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
    samples = {(scene, h, plan): [] for scene, h in CASES for plan in PLANS}
    for _ in range(REPEATS):
        for scene, h in CASES:
            for plan in PLANS:
                args = [scene, str(h), plan, str(MEMBERS), str(STEPS), str(ORDER)]
                out = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True, check=True).stdout
                samples[(scene, h, plan)].append(json.loads(out.split("JSON ", 1)[1]))
    rows = []
    for (scene, h, plan), runs in samples.items():
        row = dict(scene=scene, h=h, plan=plan, members=MEMBERS, steps=STEPS, order=ORDER,
                   fell_back=runs[0]["fell_back"], repeats=REPEATS)
        for key in ("first_call_s", "second_call_s", "backend_compile_s"):
            row[key] = statistics.median(r[key] for r in runs)
        rows.append(row)
        print(f"{scene:17s} h = {h:4}  {plan:18s}: first call {row['first_call_s']:5.2f} s (backend compile "
              f"{row['backend_compile_s']:5.2f} s), second {row['second_call_s']:.3f} s; nodes whose steps "
              f"needed the full iterations: {row['fell_back']:.0%}", flush=True)
    write_config_json("ensemble_first_call", fast_loops, rows=rows)


if __name__ == "__main__":
    main()
