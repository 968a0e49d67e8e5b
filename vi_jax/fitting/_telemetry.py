"""Telemetry of the underwater vehicle: samples at arbitrary times of any subset of the channels
a vehicle logs, each with its own noise level, missing values allowed.

Channels (space frame = the frame of the simulation, z up; body frame = the vehicle's):

- ``position`` (m, 3) [m], space frame; a missing component (NaN) is a missing sample of it, so a
  depth gauge alone is ``position`` with x and y missing;
- ``attitude`` (m, 3, 3), rotation matrices body → space (a NaN anywhere in a row's matrix: no
  attitude at that time);
- ``rates`` (m, 3) [rad/s], body angular velocity ω (gyros);
- ``velocity`` (m, 3) [m/s], body velocity ν = Rᵀq̇ (a Doppler velocity log).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._system import State
from ..engine import simulate
from ..lie import SO3


CHANNELS = ("position", "attitude", "rates", "velocity")


UNITS = {"position": "m", "attitude": "rad", "rates": "rad/s", "velocity": "m/s"}


DEFAULT_SIGMA = {"position": 0.01, "attitude": 0.01, "rates": 0.01, "velocity": 0.01}


class Telemetry(eqx.Module):
    """Samples at times ``t`` (m,) [s], strictly increasing, of the :data:`CHANNELS`; a channel
    not given (not in ``channels``) is not observed. ``values[c]`` holds the samples of every
    channel with 0 (identity for attitudes) where missing and ``mask[c]`` (m, 3) is 1 where a
    residual component is observed (an attitude's three rotation-vector components are observed
    together). ``sigma[c]``: the noise standard deviation of each component of a given channel
    [:data:`UNITS`]; ``scale[c]`` the same as arrays, with ``DEFAULT_SIGMA`` for the others."""

    t: jax.Array
    values: dict
    mask: dict
    scale: dict
    sigma: dict = eqx.field(static=True)
    channels: tuple = eqx.field(static=True)

    def __init__(self, t, *, sigma, position=None, attitude=None, rates=None, velocity=None):
        self.t = val.check_finite("t", val.as_array("t", t))
        if self.t.ndim != 1 or self.t.size < 2:
            raise ValueError(f"t: expected shape (m,) with m ≥ 2, got shape {self.t.shape}")
        steps = np.diff(np.asarray(self.t))
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise ValueError(f"t: expected strictly increasing times, got t[{i + 1}] = {float(self.t[i + 1])!r} after t[{i}] = {float(self.t[i])!r}")
        given = {"position": position, "attitude": attitude, "rates": rates, "velocity": velocity}
        given = {c: v for c, v in given.items() if v is not None}
        if not given:
            raise ValueError(f"telemetry: expected at least one of the channels {CHANNELS}")
        if not isinstance(sigma, dict) or set(sigma) != set(given):
            raise ValueError(f"sigma: expected a dict with a noise level for each channel given, {sorted(given)}, got {sigma!r}")
        m = self.t.size
        values, mask = {}, {}
        for c, v in given.items():
            shape = (m, 3, 3) if c == "attitude" else (m, 3)
            v = np.asarray(val.as_array(c, v, shape), dtype=np.float64)
            if c == "attitude":
                present = ~np.any(np.isnan(v), axis=(1, 2))
                v = np.where(present[:, None, None], v, np.eye(3))
                error = np.max(np.abs(np.einsum("nji,njk->nik", v, v) - np.eye(3)), axis=(1, 2), initial=0.0)
                bad = np.flatnonzero((error > 1e-6) | (np.abs(np.linalg.det(v) - 1) > 1e-6))
                if bad.size:
                    raise ValueError(f"attitude: row {bad[0]} is not a rotation matrix (|RᵀR − I| = {error[bad[0]]:.2g})")
                mask[c] = np.repeat(present[:, None], 3, axis=1).astype(np.float64)
            else:
                present = ~np.isnan(v)
                v = np.where(present, v, 0.0)
                mask[c] = present.astype(np.float64)
            if np.any(np.isinf(v)):
                raise ValueError(f"{c}: expected finite values or NaN for missing ones, got inf")
            values[c] = jnp.asarray(v)
            mask[c] = jnp.asarray(mask[c])
        for c in CHANNELS:
            if c not in given:
                values[c] = jnp.asarray(np.tile(np.eye(3), (m, 1, 1)) if c == "attitude" else np.zeros((m, 3)))
                mask[c] = jnp.zeros((m, 3))
        self.values, self.mask = values, mask
        self.sigma = {c: float(val.check_positive_scalar(f"sigma[{c!r}]", sigma[c])) for c in CHANNELS if c in given}
        self.channels = tuple(self.sigma)
        self.scale = {c: jnp.asarray(self.sigma.get(c, DEFAULT_SIGMA[c])) for c in CHANNELS}

    @property
    def n_observed(self) -> int:
        """Number of observed scalar residual components."""
        return int(sum(float(jnp.sum(m)) for m in self.mask.values()))

    def observed(self, channel):
        """Per component, whether any sample observes it."""
        return np.asarray(jnp.any(self.mask[channel] > 0, axis=0))


def synthesize_telemetry(model, x0, t, *, sigma, h, order=4, seed=0, outliers=0.0, outlier_scale=50.0, tau="cayley"):
    """Noisy :class:`Telemetry` of ``model`` from ``x0`` at t = 0, sampled at the times ``t``
    (≥ 0): each sample is the state of a run with step ``h`` (order ``order``) that passes through
    it exactly (``vj.simulate`` to the last grid node before it, then one partial step), plus
    Gaussian noise (attitude: R·exp(σ ε̂)) on the channels in ``sigma``. A fraction
    ``outliers`` of the samples of each channel carry ``outlier_scale``·σ noise instead."""
    t = np.asarray(t, dtype=np.float64)
    if np.any(t < 0):
        raise ValueError("t: expected times ≥ 0 (the initial state is at t = 0)")
    k = np.floor(t / h + 1e-12).astype(int)
    n = int(k.max()) + 1
    sol = simulate(model, x0, h, n, order=order, tau=tau)
    R, omega, q, nu = (np.asarray(a) for a in (sol.R, sol.omega, sol.q, sol.nu))

    def partial(i):
        x = State(g=jnp.asarray(R[k[i]]), xi=jnp.asarray(omega[k[i]]), q=jnp.asarray(q[k[i]]), qdot=jnp.asarray(R[k[i]] @ nu[k[i]]))
        dt = t[i] - k[i] * h
        if dt <= 1e-12 * max(h, 1.0):
            return R[k[i]], omega[k[i]], q[k[i]], nu[k[i]]
        s = simulate(model, x, dt, 1, order=order, tau=tau)
        return tuple(np.asarray(a[-1]) for a in (s.R, s.omega, s.q, s.nu))

    states = [partial(i) for i in range(t.size)]
    exact = {
        "attitude": np.stack([s[0] for s in states]),
        "rates": np.stack([s[1] for s in states]),
        "position": np.stack([s[2] for s in states]),
        "velocity": np.stack([s[3] for s in states]),
    }
    rng = np.random.default_rng(seed)
    noisy = {}
    for c in CHANNELS:
        if c not in sigma:
            continue
        scale = np.where(rng.random((t.size, 1)) < outliers, outlier_scale, 1.0) * sigma[c]
        eps = scale * rng.normal(size=(t.size, 3))
        if c == "attitude":
            noisy[c] = np.einsum("nij,njk->nik", exact[c], np.asarray(jax.vmap(SO3().exp)(jnp.asarray(eps))))
        else:
            noisy[c] = exact[c] + eps
    return Telemetry(t, sigma=dict(sigma), **noisy)
