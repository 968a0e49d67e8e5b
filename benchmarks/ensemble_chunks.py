"""Members per chunk of the generated batched step on CPU: ``vj.ensemble`` (1024 members × 1000
steps, final node saved, Cayley) with the chunk size forced to 64, 256, 512 and 1024, compiled
code only (median of 5); the vehicle at order 1 through the generated step, not its hand
kernel. Decided ``members_per_chunk`` (``vi_jax/engine/_generated_step.py``): with default XLA
512 members (``LIGHT_CHUNK``) where the residual with its Jacobian has at most 1000 operations
per member (the rigid body, the order-1 heavy top and vehicle: a thunk costs the same for 512
members as for 64), else 64 (``CHUNK``; the order-2 scenes lose up to 2× at 256 or 512); with
the loop option 64 everywhere. Printed with each row: those operations (``newton_operations``)
and the chunk size ``vj.ensemble`` picks.

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
from vi_jax.discrete import composition_coefficients  # noqa: E402
from vi_jax.engine import _ensemble, _generated_step  # noqa: E402
from vi_jax.lie import difference_map  # noqa: E402

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
        axes = (jax.tree.map(lambda _: system_axes, model), jax.tree.map(lambda _: 0, states))
        scheme = (model, states, axes, jnp.asarray(h), difference_map("cayley"), composition_coefficients(order)[0], n)
        picked, operations = _generated_step.members_per_chunk(*scheme), _generated_step.newton_operations(*scheme)
        for chunk in (64, 256, 512, 1024):
            _ensemble.members_per_chunk = lambda *args, chunk=chunk: chunk
            jax.clear_caches()  # the chunk is read at trace time
            run = eqx.filter_jit(lambda m, s, h, order=order, ax=system_axes: vj.ensemble(m, s, h, steps, order=order, save_every=steps, system_axes=ax, method="batched", throw=False).g[:, -1])
            compile_s, t, _ = time_compiled(run, model, states, jnp.asarray(h), repeats=5)
            rows.append(dict(scene=name, order=order, chunk=chunk, picked=picked, newton_operations=operations, members=n, steps=steps, seconds=t, rate=n * steps / t, compile_s=compile_s))
            print(f"{name:30s} order {order} chunk {chunk:5d}: {n * steps / t / 1e6:6.2f} M member-steps/s (compile {compile_s:.1f} s; {operations} operations per member in the residual with its Jacobian: picked {picked})", flush=True)
    write_config_json("ensemble_chunks", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
