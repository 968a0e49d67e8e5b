"""What the benchmarks of the generated batched step share: its members' initial states."""

import numpy as np


def perturbed_states(x0, n):
    """``n`` members: ``x0`` with its body velocity perturbed by 0.05 × a standard normal (seed 0)."""
    import vi_jax as vj  # imported on use: the scripts configure JAX first

    return vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(n, 3)))
