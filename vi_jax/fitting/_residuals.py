"""Whitened residuals of the vehicle's simulated positions and attitudes against observations,
the loss, and the forward-mode Jacobian through the implicit steps."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..engine import simulate
from ._observations import OBSERVED


def _vee_skew(A):
    return 0.5 * jnp.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]], -1)


def residuals(theta, param, x0, obs, weights, *, tau="cayley", order=1):
    """Whitened residuals times ``weights`` (position rows of samples 1..n, then attitude rows),
    and whether every step of the simulation succeeded."""
    sol = simulate(
        param.decode(theta), x0, obs.h, obs.n_steps, save_every=obs.save_every, tau=tau, order=order, throw=False
    )
    position = (sol.q[1:] - obs.q[1:]) / obs.sigma_position
    attitude = _vee_skew(jnp.einsum("nji,njk->nik", obs.R[1:], sol.R[1:])) / obs.sigma_attitude
    return jnp.concatenate([position.ravel(), attitude.ravel()]) * weights, sol.succeeded


@eqx.filter_jit
def _loss(theta, param, x0, obs, weights, tau, order):
    """½·Σr²/Σw; +inf where a step fails, so that the optimiser backs off."""
    r, ok = residuals(theta, param, x0, obs, weights, tau=tau, order=order)
    return jnp.where(ok, 0.5 * jnp.sum(r**2) / jnp.sum(weights), jnp.inf)


@eqx.filter_jit
def _jacobian(theta, param, x0, obs, weights, tau, order):
    """Residuals, their forward-mode Jacobian w.r.t. all of θ, and success."""
    f = lambda t: residuals(t, param, x0, obs, weights, tau=tau, order=order)  # noqa: E731
    (r, ok), J = f(theta), jax.jacfwd(lambda t: f(t)[0])(theta)
    return r, J, ok


def _weights(obs, fraction=1.0, observed=OBSERVED):
    """1 on the residual rows of the first ``fraction`` of the samples and of the ``observed``
    quantities, 0 elsewhere."""
    observed = (observed,) if isinstance(observed, str) else tuple(observed)
    if not observed or any(o not in OBSERVED for o in observed):
        raise ValueError(f"observed: expected a non-empty subset of {OBSERVED}, got {observed!r}")
    n = obs.n_samples
    rows = np.repeat(np.arange(n) < max(1, round(fraction * n)), 3).astype(float)
    return jnp.asarray(np.concatenate([rows * ("position" in observed), rows * ("attitude" in observed)]))
