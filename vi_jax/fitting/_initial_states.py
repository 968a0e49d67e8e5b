"""First guesses of the vehicle's state at given times from telemetry: a local quadratic
least-squares fit to the ``WINDOW`` nearest samples of each observed component gives its value
and rate; attitudes are fitted in the rotation-vector chart at the nearest sample. What the data
do not show comes from a fallback (a simulation of the first-guess model)."""

import jax
import numpy as np

from ..lie._so3 import so3_exp, so3_log

WINDOW = 5


def _window(t, present, T):
    """The ``WINDOW`` present samples nearest T, nearest first, or None where fewer than 3 are
    present."""
    idx = np.flatnonzero(present)
    if idx.size < 3:
        return None
    return idx[np.argsort(np.abs(t[idx] - T), kind="stable")[:WINDOW]]


def _local_quadratic(t, y, present, T):
    """Value and rate at T of a quadratic fitted to ``y`` at the samples of ``_window`` (or None)."""
    idx = _window(t, present, T)
    if idx is None:
        return None
    return _quadratic(t[idx] - T, y[idx])


def _quadratic(dt, y):
    A = np.stack([np.ones_like(dt), dt, dt**2], axis=1)
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    return coef[0], coef[1]


@jax.jit
def _chart(R_c, R):
    """Rotation vectors of R_cᵀR for a stack R."""
    return jax.vmap(lambda Ri: so3_log(R_c.T @ Ri))(R)


def estimate_states(telemetry, times, fallback):
    """(S, 12) states (δ, ω, q, ν) and references R̄ (S, 3, 3) at ``times``; ``fallback`` =
    (R, ω, q, ν) arrays at the same times for what the telemetry does not observe."""
    t = np.asarray(telemetry.t)
    values = {c: np.asarray(v) for c, v in telemetry.values.items()}
    mask = {c: np.asarray(m) > 0 for c, m in telemetry.mask.items()}
    R_fb, w_fb, q_fb, nu_fb = (np.array(a, dtype=np.float64) for a in fallback)
    states, refs = [], []
    for i, T in enumerate(times):
        R, omega, q, qdot = R_fb[i], w_fb[i], q_fb[i].copy(), R_fb[i] @ nu_fb[i]
        idx = _window(t, mask["attitude"][:, 0], T)
        if idx is not None:  # the chart at the nearest attitude sample
            R_c = values["attitude"][idx[0]]
            delta, omega = _quadratic(t[idx] - T, np.asarray(_chart(R_c, values["attitude"][idx])))
            R = R_c @ np.asarray(so3_exp(delta))
        for k in range(3):
            fit = _local_quadratic(t, values["rates"][:, k], mask["rates"][:, k], T)
            if fit is not None:
                omega = omega.copy()
                omega[k] = fit[0]
        for k in range(3):
            fit = _local_quadratic(t, values["position"][:, k], mask["position"][:, k], T)
            if fit is not None:
                q[k], qdot[k] = fit
        nu = R.T @ qdot
        for k in range(3):
            fit = _local_quadratic(t, values["velocity"][:, k], mask["velocity"][:, k], T)
            if fit is not None:
                nu[k] = fit[0]
        states.append(np.concatenate([np.zeros(3), omega, q, nu]))
        refs.append(R)
    return np.stack(states), np.stack(refs)
