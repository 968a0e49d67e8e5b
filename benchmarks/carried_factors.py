"""Newton's factors carried from step to step in the generated batched step, against a fresh
Jacobian every step: ``vj.ensemble`` (1024 members × 1000 steps, final node saved, Cayley,
the CPU plan), both variants compiled in one process and timed alternately (median of 7 runs
each), with the Newton iterations of both and the cost of the residual with its Jacobian in
residuals (``scene_operations``). Decided ``CARRY_COST``: the scenes whose factors are carried.

    python benchmarks/carried_factors.py [--fast-loops]
"""

import argparse

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import compiled_with_switches, perturbed_states  # noqa: E402
from vi_jax.engine import _generated_step  # noqa: E402

MEMBERS, STEPS, REPEATS = 1024, 1000, 7
CASES = [("rigid_body", vj.models.RigidBody, 0.01, 2), ("heavy_top", vj.models.HeavyTop, 0.005, 1),
         ("heavy_top", vj.models.HeavyTop, 0.005, 2), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 1),
         ("vehicle", vj.models.UnderwaterVehicle, 0.01, 2), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 4)]


def compiled(model, states, h, order, carry):
    """The run compiled ahead of time with ``CARRY_FACTORS = carry`` (caches cleared first: the
    switch is read at trace time), its worst Newton iterations and final attitudes."""
    run, sol = compiled_with_switches(model, states, h, order, STEPS, CARRY_FACTORS=carry)
    return run, int(np.max(np.asarray(sol.newton_iterations)[:, 1:])), np.asarray(sol.g[:, -1])


def jacobian_cost(model, states, h, order):
    residual, with_jacobian = _generated_step.scene_operations(model, states, h, order=order)
    return with_jacobian / residual


def main():
    rows = []
    try:
        for name, scene, h, order in CASES:
            model = scene()
            states = perturbed_states(model.initial_state(), MEMBERS)
            h = jnp.asarray(h)
            runs = {carry: compiled(model, states, h, order, carry) for carry in (False, True)}
            seconds = time_alternately({c: lambda run=run: run(model, states, h) for c, (run, _, _) in runs.items()}, REPEATS)
            rate = {c: MEMBERS * STEPS / t for c, t in seconds.items()}
            diff = float(np.max(np.abs(runs[True][2] - runs[False][2])))
            cost = jacobian_cost(model, states, h, order)
            rows.append(dict(scene=name, order=order, jacobian_cost=cost, carried_by_default=cost >= _generated_step.CARRY_COST, fresh_rate=rate[False], carried_rate=rate[True], speedup=rate[True] / rate[False],
                             worst_iterations_fresh=runs[False][1], worst_iterations_carried=runs[True][1], max_abs_g_difference=diff))
            print(f"{name:10s} order {order} (Jacobian cost {cost:.2f} residuals): fresh {rate[False] / 1e6:6.2f} M, carried {rate[True] / 1e6:6.2f} M member-steps/s "
                  f"({rate[True] / rate[False]:.2f}x); worst Newton iterations {runs[False][1]} / {runs[True][1]}; "
                  f"max |g difference| {diff:.1e}", flush=True)
    finally:
        _generated_step.CARRY_FACTORS = None
    write_config_json("carried_factors", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
