"""A concrete ``vj.simulate``'s Newton plan: the program with Newton's full iterations (what
``vj.simulate`` runs) against the program without them (``max_newton_iterations`` =
1 + ``CHORD_ITERATIONS``: one Newton step and the chord steps, which ``vj.simulate`` ran first
before Newton factored its Jacobian once per step). Every run here converges in the common path,
so the second program alone was the former plan's cost. 20,000 steps, every node saved, the
calls timed alternately in one process (median of 7 after a compiling call).

    python benchmarks/newton_plan.py [--fast-loops]
"""

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

ARGS = parse_args_with_fast_loops()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax.solvers import CHORD_ITERATIONS  # noqa: E402

N_STEPS = 20_000
CASES = [("UnderwaterVehicle", 0.01), ("HeavyTop", 0.005), ("RigidBody", 0.01)]


def main():
    calls = {}
    for scene, h in CASES:
        model = getattr(vj.models, scene)()
        x0 = model.initial_state()
        for order in (1, 2):
            for plan, max_iterations in (("full", 20), ("common", 1 + CHORD_ITERATIONS)):
                calls[(scene, order, plan)] = lambda m=model, x=x0, h=h, o=order, k=max_iterations: vj.simulate(
                    m, x, h, N_STEPS, order=o, max_newton_iterations=k)
    for call in calls.values():
        call()  # compiles; raises if a step needs more than the common path
    seconds = time_alternately(calls)
    rows = []
    for scene, _ in CASES:
        for order in (1, 2):
            full, common = seconds[(scene, order, "full")], seconds[(scene, order, "common")]
            rows.append(dict(scene=scene, order=order, full_s=full, common_s=common, ratio=full / common))
            print(f"{scene:18s} order {order}: full iterations {full:.4f} s, common path only {common:.4f} s, ratio {full / common:.2f}")
    write_config_json("newton_plan", ARGS.fast_loops, n_steps=N_STEPS, rows=rows)


if __name__ == "__main__":
    main()
