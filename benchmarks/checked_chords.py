"""Newton's chord steps checked in the generated batched step (each runs only while some
member of the chunk has not converged, masked per member), against every chord step run
unchecked: ``vj.ensemble`` (1024 members × 1000 steps, final node saved, Cayley, h = 0.01, the
CPU plan, under ``jit``), both variants compiled in one process and timed alternately (median
and fastest of 9 runs each), with the residual's operations per member
(``scene_operations``) and the mean Newton iterations per node (every 10th step saved, 200
steps). Decided ``CHECK_COST``: the scenes whose chord steps are checked.

    python benchmarks/checked_chords.py [--fast-loops]
"""

import argparse

from _timing import alternate_samples, parse_args_with_fast_loops, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ARGS = parse_args_with_fast_loops(PARSER)

import statistics  # noqa: E402

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import compiled_with_switches, perturbed_states  # noqa: E402
from vi_jax.engine import _generated_step  # noqa: E402

MEMBERS, STEPS, REPEATS, H = 1024, 1000, 9, 0.01
CASES = [("rigid_body", vj.models.RigidBody, 1), ("rigid_body", vj.models.RigidBody, 2), ("heavy_top", vj.models.HeavyTop, 1),
         ("heavy_top", vj.models.HeavyTop, 2), ("vehicle", vj.models.UnderwaterVehicle, 1), ("vehicle", vj.models.UnderwaterVehicle, 2)]


def compiled(model, states, h, order, checked):
    """The run compiled ahead of time with ``CHECK_CHORDS = checked`` (caches cleared first: the
    switch is read at trace time), its mean Newton iterations per node and final attitudes."""
    run, sol = compiled_with_switches(model, states, h, order, STEPS, CHECK_CHORDS=checked)
    nodes = vj.ensemble(model, states, h, 200, order=order, save_every=10, method="batched", throw=False)
    return run, float(np.mean(np.asarray(nodes.newton_iterations)[:, 1:])), np.asarray(sol.g[:, -1])


def main():
    rows = []
    try:
        for name, scene, order in CASES:
            model = scene()
            states = perturbed_states(model.initial_state(), MEMBERS)
            h = jnp.asarray(H)
            runs = {checked: compiled(model, states, h, order, checked) for checked in (False, True)}
            samples = alternate_samples({c: lambda run=run: run(model, states, h) for c, (run, _, _) in runs.items()}, REPEATS)
            rate = {c: MEMBERS * STEPS / statistics.median(s) for c, s in samples.items()}
            fastest = {c: MEMBERS * STEPS / min(s) for c, s in samples.items()}
            diff = float(np.max(np.abs(runs[True][2] - runs[False][2])))
            ops = _generated_step.scene_operations(model, states, h, order=order)[0]
            rows.append(dict(scene=name, order=order, residual_operations=ops, checked_by_default=ops >= _generated_step.CHECK_COST,
                             unchecked_rate=rate[False], checked_rate=rate[True], speedup=rate[True] / rate[False],
                             speedup_fastest=fastest[True] / fastest[False], mean_iterations_unchecked=runs[False][1],
                             mean_iterations_checked=runs[True][1], max_abs_g_difference=diff))
            print(f"{name:10s} order {order} ({ops} operations a residual): unchecked {rate[False] / 1e6:6.2f} M, checked {rate[True] / 1e6:6.2f} M "
                  f"member-steps/s ({rate[True] / rate[False]:.2f}x by medians, {fastest[True] / fastest[False]:.2f}x by the fastest); "
                  f"mean Newton iterations {runs[False][1]:.2f} / {runs[True][1]:.2f}; max |g difference| {diff:.1e}", flush=True)
    finally:
        _generated_step.CHECK_CHORDS = None
    write_config_json("checked_chords", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
