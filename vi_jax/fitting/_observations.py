"""Observations of the underwater vehicle: positions and attitudes sampled on the step grid,
with their noise levels, and synthetic noisy records of a simulated run."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val

from ..engine import simulate
from ..lie import SO3


class Observations(eqx.Module):
    """Positions ``q`` (n+1, 3) [m] and attitudes ``R`` (n+1, 3, 3) sampled every
    ``save_every`` steps of size ``h`` from t = 0 (row 0: the known initial state), with noise
    standard deviations ``sigma_position`` [m] and ``sigma_attitude`` [rad]."""

    q: jax.Array
    R: jax.Array
    h: float = eqx.field(static=True)
    save_every: int = eqx.field(static=True)
    sigma_position: float = eqx.field(static=True)
    sigma_attitude: float = eqx.field(static=True)

    def __init__(self, q, R, h, save_every, sigma_position, sigma_attitude):
        self.q = val.check_finite("q", val.as_array("q", q))
        self.R = val.check_finite("R", val.as_array("R", R))
        if self.q.ndim != 2 or self.q.shape[1] != 3 or self.q.shape[0] < 2:
            raise ValueError(f"q: expected shape (n + 1, 3) with n ≥ 1, got shape {self.q.shape}")
        val.as_array("R", self.R, (self.q.shape[0], 3, 3))
        self.h = float(val.check_positive_scalar("h", h))
        self.save_every = val.check_int("save_every", save_every, 1)
        self.sigma_position = float(val.check_positive_scalar("sigma_position", sigma_position))
        self.sigma_attitude = float(val.check_positive_scalar("sigma_attitude", sigma_attitude))

    @property
    def n_samples(self):
        return self.q.shape[0] - 1

    @property
    def n_steps(self):
        return self.n_samples * self.save_every


def synthesize(model, x0, h, n_steps, *, save_every, sigma_position, sigma_attitude, seed=0, tau="cayley"):
    """Noisy :class:`Observations` of ``vj.simulate(model, x0, h, n_steps)``: Gaussian position
    noise and attitude noise R·exp(σ ε̂), ε ~ N(0, I) (row 0 stays exact)."""
    sol = simulate(model, x0, h, n_steps, save_every=save_every, tau=tau)
    rng = np.random.default_rng(seed)
    n = sol.q.shape[0]
    noise = lambda sigma: sigma * np.concatenate([np.zeros((1, 3)), rng.normal(size=(n - 1, 3))])  # noqa: E731
    q = np.asarray(sol.q) + noise(sigma_position)
    R = np.einsum("nij,njk->nik", np.asarray(sol.R), np.asarray(jax.vmap(SO3().exp)(jnp.asarray(noise(sigma_attitude)))))
    return Observations(q, R, h, save_every, sigma_position, sigma_attitude)
