"""Newton's first guess in the generated batched step: the extrapolation 2ξ_k − ξ_{k−1} (error
O(h²)) against the last step's ξ_k (error O(h)). ``vj.ensemble`` (1024 members × 1000 steps,
final node saved, Cayley, the CPU plan), both variants compiled in one process and timed
alternately (median of 7 runs each), with the share of member-steps that needed Newton's
fallback iterations (more than one Newton and two chord steps) in a 64-member × 300-step run
with every node saved.

``--whole-batch``: the accelerator plan run on the CPU (every member in every kernel, no fusion
boundaries: what a GPU runs), 262,144 members × 50 steps, the GPU benchmark's cases
(``ensemble_gpu.py``: the vehicle at order 1, the heavy top at orders 1 and 2); on an H200 the
extrapolation cost 1.05–1.67× there at 2²⁰ members (``ensemble_gpu.py``), and this asks how
much of that the CPU sees (the accelerator plan now starts from ξ_k: ``gpu_step_profile.py``).

    python benchmarks/extrapolated_guess.py [--fast-loops] [--whole-batch]
"""

import argparse

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--whole-batch", action="store_true", help="the accelerator plan (every member in every kernel), on the CPU")
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import compiled_with_switches, perturbed_states  # noqa: E402
from vi_jax.engine import _ensemble, _generated_step  # noqa: E402

MEMBERS, STEPS, REPEATS = 1024, 1000, 7
VARIANTS = {"last xi": False, "extrapolated": True}
# The step sizes, then larger ones where the fallback runs.
CASES = [("rigid_body", vj.models.RigidBody, 0.01, 2), ("heavy_top", vj.models.HeavyTop, 0.005, 1),
         ("heavy_top", vj.models.HeavyTop, 0.005, 2), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 2),
         ("heavy_top", vj.models.HeavyTop, 0.01, 1), ("heavy_top", vj.models.HeavyTop, 0.01, 2),
         ("heavy_top", vj.models.HeavyTop, 0.02, 2), ("rigid_body", vj.models.RigidBody, 0.05, 2)]
if ARGS.whole_batch:
    MEMBERS, STEPS = 262_144, 50
    CASES = [("vehicle", vj.models.UnderwaterVehicle, 0.01, 1), ("heavy_top", vj.models.HeavyTop, 0.005, 1),
             ("heavy_top", vj.models.HeavyTop, 0.005, 2)]
    _ensemble.target_platform = lambda mesh=None: "gpu"


def fallback_share(model, h, order):
    """Share of member-steps whose Newton iterations exceeded one Newton and two chord steps."""
    states = perturbed_states(model.initial_state(), 64)
    sol = vj.ensemble(model, states, h, 300, order=order, method="batched", throw=False)
    return float(np.mean(np.asarray(sol.newton_iterations)[:, 1:] > 3))


def compiled(model, states, h, order, predict):
    """The run compiled ahead of time with the extrapolated guess or not (``PREDICT``, or
    ``PREDICT_ON_ACCELERATORS`` with ``--whole-batch``; caches cleared first: the switches are
    read at trace time), its fallback share and final attitudes."""
    run, sol = compiled_with_switches(model, states, h, order, STEPS, PREDICT=predict, PREDICT_ON_ACCELERATORS=predict)
    g = np.asarray(sol.g[:, -1])
    return run, fallback_share(model, float(h), order), g


def main():
    rows = []
    try:
        for name, scene, h, order in CASES:
            model = scene()
            states = perturbed_states(model.initial_state(), MEMBERS)
            h = jnp.asarray(h)
            runs = {v: compiled(model, states, h, order, p) for v, p in VARIANTS.items()}
            seconds = time_alternately({v: lambda run=run: run(model, states, h) for v, (run, _, _) in runs.items()}, REPEATS)
            rate = {v: MEMBERS * STEPS / t for v, t in seconds.items()}
            share = {v: runs[v][1] for v in runs}
            diff = float(np.max(np.abs(runs["extrapolated"][2] - runs["last xi"][2])))
            rows.append(dict(scene=name, order=order, h=float(h), rates=rate, fallback_share=share,
                             speedup=rate["extrapolated"] / rate["last xi"], max_abs_g_difference=diff))
            print(f"{name:10s} order {order} h {float(h):5.3f}: " + ", ".join(f"{v} {r / 1e6:5.2f} M" for v, r in rate.items())
                  + f" member-steps/s ({rows[-1]['speedup']:.2f}x); fallback in "
                  + ", ".join(f"{100 * s:.1f}%" for s in share.values()) + f" of member-steps; max |Δg| {diff:.1e}", flush=True)
    finally:
        _generated_step.PREDICT, _generated_step.PREDICT_ON_ACCELERATORS = True, False
    name = "extrapolated_guess_whole_batch" if ARGS.whole_batch else "extrapolated_guess"
    write_config_json(name, ARGS.fast_loops, members=MEMBERS, steps=STEPS, rows=rows)


if __name__ == "__main__":
    main()
