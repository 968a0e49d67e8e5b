"""Members per chunk of the generated batched step on CPU: ``vj.ensemble`` (1024 members × 1000
steps, final node saved, Cayley) with the chunk size forced to 64, 256, 512 and 1024, compiled
code only (median of 5); the vehicle at order 1 through the generated step, not its hand
kernel. Decided ``CHUNK`` (``vi_jax/engine/_member_split.py``): 64 members, each chunk's loops
one kernel (``vi_jax/_one_kernel.py``). Before the loops were one kernel with default XLA flags,
512 members ran 1.19-1.53x faster than 64 for the light scenes there (a dispatch per fused
operation cost the same for 512 members as for 64).

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
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax.engine import _ensemble  # noqa: E402

CASES = [("heavy_top", vj.models.HeavyTop, 0.005, 1), ("heavy_top", vj.models.HeavyTop, 0.005, 2),
         ("rigid_body", vj.models.RigidBody, 0.01, 2), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 1),
         ("vehicle", vj.models.UnderwaterVehicle, 0.01, 2),
         ("rigid_body, inertia per member", vj.models.RigidBody, 0.01, 2),
         ("vehicle, mass per member", vj.models.UnderwaterVehicle, 0.01, 1)]


def per_member(name, model, n):
    """The scene, with one parameter per member where the case says so, and its axes."""
    if "inertia per member" in name:
        return vj.vary(model, inertia=model.inertia * np.linspace(0.98, 1.02, n)[:, None, None]), 0
    if "mass per member" in name:
        return vj.vary(model, mass=model.mass * np.linspace(0.98, 1.02, n)), 0
    return model, None


def main():
    n, steps = ARGS.members, ARGS.steps
    rows = []
    for name, scene, h, order in CASES:
        model, system_axes = per_member(name, scene(), n)
        states = perturbed_states(scene().initial_state(), n)
        for chunk in (64, 256, 512, 1024):
            _ensemble.CHUNK = chunk
            jax.clear_caches()  # the chunk is read at trace time
            run = eqx.filter_jit(lambda m, s, h, order=order, ax=system_axes: vj.ensemble(m, s, h, steps, order=order, save_every=steps, system_axes=ax, method="batched", throw=False).g[:, -1])
            compile_s, t, _ = time_compiled(run, model, states, jnp.asarray(h), repeats=5)
            rows.append(dict(scene=name, order=order, chunk=chunk, members=n, steps=steps, seconds=t, rate=n * steps / t, compile_s=compile_s))
            print(f"{name:30s} order {order} chunk {chunk:5d}: {n * steps / t / 1e6:6.2f} M member-steps/s (compile {compile_s:.1f} s)", flush=True)
    write_config_json("ensemble_chunks", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
