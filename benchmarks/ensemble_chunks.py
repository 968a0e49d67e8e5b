"""Members per chunk of the generated batched step on CPU: ``vj.ensemble`` (1024 members × 1000
steps, final node saved, Cayley) with the chunk size forced to 64, 256, 512 and 1024, compiled
code only (median of 5). Keeps ``CHUNK`` = 64. Run on 6060d65 (carried factors for the order-2
scenes), default XLA: 512 is 1.36× (heavy top, order 1) and 1.57× (rigid body, order 2) faster
than 64, a thunk costing the same for 512 members as for 64; but 0.45–0.99× for the order-2
scenes at 256 or 512 (the heavy top 1.34× at 1024) and 0.93× for the rigid body at 1024: XLA:CPU splits a fusion over the cores once
its cost model's estimate passes a threshold (``outer_dimension_partitions`` in the optimised
HLO: 2 fusions of the order-2 heavy top at 64 members, 70 at 512), and which fusions it splits,
at which size, varies by scene. With the loop option 64 is within 3.1% of the best size for every
scene; 512 and 1024 give 0.71–0.99×.

    python benchmarks/ensemble_chunks.py [--members 1024] [--steps 1000] [--fast-loops]
"""

import argparse

from _timing import parse_args_with_fast_loops, time_compiled, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=1024)
PARSER.add_argument("--steps", type=int, default=1000)
ARGS = parse_args_with_fast_loops(PARSER)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax.engine import _ensemble  # noqa: E402

CASES = [("heavy_top", vj.models.HeavyTop, 0.005, 1), ("heavy_top", vj.models.HeavyTop, 0.005, 2),
         ("rigid_body", vj.models.RigidBody, 0.01, 2), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 2)]


def main():
    n, steps = ARGS.members, ARGS.steps
    rows = []
    for name, scene, h, order in CASES:
        model = scene()
        x0 = model.initial_state()
        states = perturbed_states(x0, n)
        for chunk in (64, 256, 512, 1024):
            _ensemble.CHUNK = chunk
            run = eqx.filter_jit(lambda m, s, h, order=order: vj.ensemble(m, s, h, steps, order=order, save_every=steps, method="batched", throw=False).g[:, -1])
            compile_s, t, _ = time_compiled(run, model, states, jnp.asarray(h), repeats=5)
            rows.append(dict(scene=name, order=order, chunk=chunk, members=n, steps=steps, seconds=t, rate=n * steps / t, compile_s=compile_s))
            print(f"{name:10s} order {order} chunk {chunk:5d}: {n * steps / t / 1e6:6.2f} M member-steps/s (compile {compile_s:.1f} s)", flush=True)
    write_config_json("ensemble_chunks", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
