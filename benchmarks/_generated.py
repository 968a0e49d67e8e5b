"""What the benchmarks of the generated batched step share: its members' initial states and a
switch that sends every scene through it (the vehicle at order 1 included, which ``vj.ensemble``
otherwise runs with its hand kernel)."""

import contextlib

import numpy as np


def perturbed_states(x0, n):
    """``n`` members: ``x0`` with its body velocity perturbed by 0.05 × a standard normal (seed 0)."""
    import vi_jax as vj  # imported on use: the scripts configure JAX first

    return vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(n, 3)))


@contextlib.contextmanager
def generated_step_for_every_scene(enabled=True):
    """While active (and ``enabled``), ``vj.ensemble`` runs the generated step for every scene."""
    from vi_jax.engine import _ensemble

    real = _ensemble._vehicle_kernel_applies
    if enabled:
        _ensemble._vehicle_kernel_applies = lambda *args: False
    try:
        yield
    finally:
        _ensemble._vehicle_kernel_applies = real
