"""``vj.ensemble`` under a caller's ``jit`` that closes over the scene and h (XLA sees them as
constants) against one that passes them as arguments, with the batched steps' inputs behind an
optimisation barrier (``_opaque`` in ``vi_jax/engine/_ensemble.py``) and without: 1024 members ×
1000 steps, final node saved, Cayley, order 1 (results/closed_over_inputs*.json measured the
vehicle on its former hand kernel, which the barrier did not wrap), compiled code only, the variants
timed alternately in one process (median of 5).

    python benchmarks/closed_over_inputs.py [--fast-loops]
        [--members 1024] [--steps 1000] [--order 1] [--scenes vehicle heavy_top rigid_body] [--out FILE]

On a GPU the generated step has no fusion boundaries to keep (its plan fuses the whole batch),
so there the question is only what the barrier costs: e.g. ``--members 1048576 --steps 238
--scenes heavy_top rigid_body --order 1`` (and ``--order 2``).
"""

import argparse
import time

from _timing import parse_args_with_fast_loops, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=1024)
PARSER.add_argument("--steps", type=int, default=1000)
PARSER.add_argument("--order", type=int, default=1)
PARSER.add_argument("--scenes", nargs="+", default=["vehicle", "heavy_top", "rigid_body"])
PARSER.add_argument("--out", default=None, help="JSON path (default: benchmarks/results/closed_over_inputs[_fast_loops].json)")
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax.engine import _ensemble  # noqa: E402

MEMBERS, STEPS, ORDER, REPEATS = ARGS.members, ARGS.steps, ARGS.order, 5
SCENES = {"vehicle": (vj.models.UnderwaterVehicle, 0.01), "heavy_top": (vj.models.HeavyTop, 0.005), "rigid_body": (vj.models.RigidBody, 0.01)}
OPAQUE = _ensemble._opaque


def compiled(model, states, h, closed_over, barrier):
    """The run compiled ahead of time (caches cleared: the barrier is chosen at trace time)."""
    jax.clear_caches()
    _ensemble._opaque = OPAQUE if barrier else lambda dynamic, h: (dynamic, h)
    run = lambda m, s, h: vj.ensemble(m, s, h, STEPS, order=ORDER, save_every=STEPS, throw=False).g[:, -1]  # noqa: E731
    if closed_over:
        fn = jax.jit(lambda s: run(model, s, float(h))).lower(states).compile()
        return lambda: fn(states)
    fn = jax.jit(run).lower(model, states, jnp.asarray(h)).compile()
    return lambda: fn(model, states, jnp.asarray(h))


def main():
    rows = []
    try:
        for name in ARGS.scenes:
            scene, h = SCENES[name]
            model = scene()
            states = perturbed_states(model.initial_state(), MEMBERS)
            variants = {(c, b): compiled(model, states, h, c, b) for c in (False, True) for b in (False, True)}
            times = {v: [] for v in variants}
            for _ in range(REPEATS):
                for v, run in variants.items():
                    jax.block_until_ready(run())
                    t0 = time.perf_counter()
                    jax.block_until_ready(run())
                    times[v].append(time.perf_counter() - t0)
            rate = {v: MEMBERS * STEPS / float(np.median(t)) for v, t in times.items()}
            label = lambda c, b: f"{'closed over' if c else 'arguments'}, {'barrier' if b else 'no barrier'}"  # noqa: E731
            rows.append(dict(scene=name, order=ORDER, members=MEMBERS, steps=STEPS, rates={label(*v): r for v, r in rate.items()}))
            print(f"{name:10s}: " + ", ".join(f"{label(*v)} {r / 1e6:5.2f} M" for v, r in rate.items()) + " member-steps/s", flush=True)
    finally:
        _ensemble._opaque = OPAQUE
    write_config_json("closed_over_inputs", ARGS.fast_loops, ARGS.out, device=str(jax.devices()[0]), jax=jax.__version__, rows=rows)


if __name__ == "__main__":
    main()
