"""A concrete ``vj.ensemble`` call whose members need Newton's full iterations, where the
generated step carries its factors and checks its chord steps: the full program (run after the
program without the full iterations, ``vi_jax.engine._ensemble.optimistically``) with Newton's
iterations rolled into one loop (``ROLL_FULL_ITERATIONS = True``: the residual and its Jacobian
compiled once each) against unrolled (the residual four times, the Jacobian twice). A user
``vj.System`` (SO(3), advected parameter, additional dynamics, a ξ–ν cross term; the tests' own) at
orders 2 and 4, h = 0.01, 1024 members × 1000 steps, final node saved: each variant in fresh
processes, alternately, ``REPEATS`` times; the median first call (trace + compile + run), its
backend compile (JAX's monitoring events: both programs, the one without the full iterations
unrolled either way) and the median of 7 later calls (each runs both programs) are reported,
with the largest difference of the two variants' final ξ.

    python benchmarks/rolled_full_iterations.py [--fast-loops]
"""

import numpy as np
from _timing import fast_loops_from_argv, fresh_process_runs, medians, write_config_json

ORDERS = (2, 4)
VARIANTS = {"rolled": True, "unrolled": False}
MEMBERS, STEPS, H, REPEATS = 1024, 1000, 0.01, 2

CHILD = """
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
from jax._src import monitoring
compile_s = []
monitoring.register_event_duration_secs_listener(
    lambda event, duration, **_: compile_s.append(duration) if event.endswith("backend_compile_duration") else None)
import jax.numpy as jnp
import numpy as np
import vi_jax as vj
from vi_jax.engine import _generated_step
from vi_jax.lie import SO3, LinearAction
order, rolled, members, steps, h = int(sys.argv[1]), sys.argv[2] == "True", int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
_generated_step.ROLL_FULL_ITERATIONS = rolled
J, M = np.diag([2.0, 3.0, 4.0]), np.diag([5.0, 6.0, 7.0])
lagrangian = lambda xi, n, nu, a, p: 0.5 * xi @ J @ xi + 0.5 * nu @ M @ nu + 0.4 * xi @ nu - p * n @ a
system = vj.System(SO3(), lagrangian, jnp.asarray(9.81), advected=(LinearAction(SO3()), np.eye(3)[2]), additional=LinearAction(SO3()))
x0 = vj.State(jnp.eye(3), jnp.array([0.3, -0.2, 0.5]), jnp.zeros(3), jnp.array([0.1, 0.0, -0.2]))
states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.01 * np.random.default_rng(0).normal(size=(members, 3)))
run = lambda: vj.ensemble(system, states, h, steps, order=order, save_every=steps)
start = time.perf_counter()
sol = jax.block_until_ready(run())
first = time.perf_counter() - start
later = []
for _ in range(7):
    start = time.perf_counter()
    jax.block_until_ready(run())
    later.append(time.perf_counter() - start)
fell_back = float(np.mean(np.asarray(sol.newton_iterations[:, 1:]) > 3))
print("JSON " + json.dumps(dict(first_call_s=first, backend_compile_s=sum(compile_s), later_call_s=float(np.median(later)),
                                 fell_back=fell_back, final_xi=np.asarray(sol.xi[:, -1]).tolist())))
"""


def main():
    fast_loops = fast_loops_from_argv()
    cases = {(order, name): [order, rolled, MEMBERS, STEPS, H] for order in ORDERS for name, rolled in VARIANTS.items()}
    samples = fresh_process_runs(CHILD, cases, REPEATS)
    rows = []
    for order in ORDERS:
        xi = [np.asarray(samples[(order, name)][0]["final_xi"]) for name in VARIANTS]
        gap = float(np.max(np.abs(xi[0] - xi[1])))
        for name in VARIANTS:
            runs = samples[(order, name)]
            row = dict(order=order, variant=name, members=MEMBERS, steps=STEPS, h=H, repeats=REPEATS,
                       members_needing_full_iterations=runs[0]["fell_back"], final_xi_max_difference=gap)
            row.update(medians(runs, ("first_call_s", "backend_compile_s", "later_call_s")))
            rows.append(row)
            print(f"order {order} {name:9s}: first call {row['first_call_s']:5.2f} s (backend compile "
                  f"{row['backend_compile_s']:5.2f} s), later calls {1e3 * row['later_call_s']:7.1f} ms; members "
                  f"needing the full iterations {row['members_needing_full_iterations']:.1%}; final xi apart by {gap:.1e}", flush=True)
    write_config_json("rolled_full_iterations", fast_loops, rows=rows)


if __name__ == "__main__":
    main()
