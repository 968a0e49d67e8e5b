"""What the benchmarks of the generated batched step share: its members' initial states, and runs
compiled with the step's module switches set."""

import numpy as np


def perturbed_states(x0, n):
    """``n`` members: ``x0`` with its body velocity perturbed by 0.05 × a standard normal (seed 0)."""
    import vi_jax as vj  # imported on use: the scripts configure JAX first

    return vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(n, 3)))


def compiled_with_switches(model, states, h, order, steps, **switches):
    """``vj.ensemble`` of the generated step (final node saved) under ``jit``, compiled ahead of
    time with the module switches of ``vi_jax.engine._generated_step`` set to ``switches`` (caches
    cleared first: the switches are read at trace time), and its first run's solution."""
    import jax
    import vi_jax as vj
    from vi_jax.engine import _generated_step

    jax.clear_caches()
    for name, value in switches.items():
        setattr(_generated_step, name, value)
    run = jax.jit(lambda m, s, h: vj.ensemble(m, s, h, steps, order=order, save_every=steps, method="batched", throw=False))
    run = run.lower(model, states, h).compile()
    return run, jax.block_until_ready(run(model, states, h))
