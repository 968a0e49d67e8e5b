"""Reverse mode through an ensemble (the vehicle's batched step, Cayley, order 1, h = 0.01,
float64): XLA's temporary memory and the gradient/forward time ratio, with ``checkpoint=True``
(``vj.ensemble``'s default) and ``checkpoint=False``.

    python benchmarks/ensemble_gradients.py [--members 256] [--steps 1000 10000] [--fast-loops]

Loss: the members' final positions (``save_every = n_steps``), gradient with respect to every
member's parameters (``vary`` over the mass). Memory: the jitted gradient's compiled memory
analysis (temporary buffers); times: compiled code, median of 5, in one process.
"""

import argparse

from _timing import parse_args_with_fast_loops, time_compiled, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=256)
PARSER.add_argument("--steps", type=int, nargs="+", default=[1000, 10_000])
ARGS = parse_args_with_fast_loops(PARSER)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402


def main():
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    models = vj.vary(model, mass=jnp.linspace(118.0, 128.0, ARGS.members))
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(ARGS.members, 3)))
    rows = []
    for n in ARGS.steps:
        def loss(models, checkpoint, n=n):
            sol = vj.ensemble(models, states, 0.01, n, system_axes=0, save_every=n, checkpoint=checkpoint, throw=False)
            return jnp.sum(sol.q[:, -1] ** 2)

        dynamic, static = eqx.partition(models, eqx.is_array)
        forward = jax.jit(lambda d: loss(eqx.combine(d, static), True))
        _, t_forward, _ = time_compiled(forward, dynamic, repeats=5)
        for checkpoint in (True, False):
            grad = jax.jit(jax.grad(lambda d, c=checkpoint: loss(eqx.combine(d, static), c)))
            temp = grad.lower(dynamic).compile().memory_analysis().temp_size_in_bytes
            first, t_grad, _ = time_compiled(grad, dynamic, repeats=5)
            rows.append(dict(members=ARGS.members, steps=n, checkpoint=checkpoint, temp_bytes=int(temp),
                             forward_s=t_forward, gradient_s=t_grad, ratio=t_grad / t_forward, compile_and_first_s=first))
            print(f"{ARGS.members} members x {n:6d} steps, checkpoint={checkpoint!s:5s}: temporaries {temp / 2**20:9.2f} MiB, "
                  f"gradient {t_grad / t_forward:5.2f}x the forward pass ({t_forward * 1e3:.1f} ms)", flush=True)
    write_config_json("ensemble_gradients", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
