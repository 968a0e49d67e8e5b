"""The generated step's member loops as one kernel (``vi_jax/_one_kernel.py``) against XLA:CPU's
thunk per fused operation, with the process's XLA flags (run it with and without
``--fast-loops``): ``vj.ensemble`` under ``jit`` (scene, states and h as arguments; 1024 members ×
1000 steps, final node saved, Cayley), three plans compiled in one process and timed alternately
(median of 7):

- ``thunks, 512``: the loops left to XLA:CPU's default plan, 512 members per chunk (the plan
  before, with default flags, for the light scenes: the order-1 scenes and the order-2 rigid body);
- ``thunks, 64``: the same with 64 members per chunk (the plan before for the order-2 vehicle and
  heavy top, and with the loop option for every scene);
- ``one kernel, 64``: this version's plan.

    python benchmarks/one_kernel_loops.py [--members 1024] [--steps 1000] [--fast-loops]
"""

import argparse

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=1024)
PARSER.add_argument("--steps", type=int, default=1000)
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax.engine import _ensemble, _generated_step  # noqa: E402

SCENES = [("vehicle", vj.models.UnderwaterVehicle, 0.01, 1), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 2),
          ("heavy_top", vj.models.HeavyTop, 0.005, 1), ("heavy_top", vj.models.HeavyTop, 0.005, 2),
          ("rigid_body", vj.models.RigidBody, 0.01, 1), ("rigid_body", vj.models.RigidBody, 0.01, 2)]
PLANS = {"thunks, 512": (False, 512), "thunks, 64": (False, 64), "one kernel, 64": (True, 64)}


def compiled(model, states, h, order, kernel, chunk):
    """The program of one plan (the plan is read at trace time)."""
    real = _generated_step.one_kernel
    _generated_step.one_kernel = real if kernel else (lambda fn: fn)
    _ensemble.CHUNK = chunk
    jax.clear_caches()
    try:
        run = jax.jit(lambda m, s, h: vj.ensemble(m, s, h, ARGS.steps, order=order, save_every=ARGS.steps, method="batched", throw=False).g[:, -1])
        return run.lower(model, states, h).compile()
    finally:
        _generated_step.one_kernel = real


def main():
    rows = []
    for name, scene, h, order in SCENES:
        model = scene()
        states = perturbed_states(model.initial_state(), ARGS.members)
        h = jnp.asarray(h)
        programs = {plan: compiled(model, states, h, order, *how) for plan, how in PLANS.items()}
        outs = {plan: program(model, states, h) for plan, program in programs.items()}
        seconds = time_alternately({plan: (lambda p=program: p(model, states, h)) for plan, program in programs.items()})
        spread = max(float(jnp.max(jnp.abs(outs[p] - outs["one kernel, 64"]))) for p in PLANS)
        rate = {plan: ARGS.members * ARGS.steps / s / 1e6 for plan, s in seconds.items()}
        rows.append(dict(scene=name, order=order, members=ARGS.members, steps=ARGS.steps, seconds=seconds, rate_M=rate, max_abs_difference=spread))
        print(f"{name:10s} order {order}: " + ", ".join(f"{p} {r:6.2f} M" for p, r in rate.items())
              + f"; one kernel / best thunk plan {rate['one kernel, 64'] / max(rate['thunks, 512'], rate['thunks, 64']):.2f}x (max |Δg| {spread:.1e})", flush=True)
    write_config_json("one_kernel_loops", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
