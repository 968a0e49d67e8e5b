"""Identifiability from the Fisher information: rank, null directions and uncertainties of the
whitened Jacobian, per set of known parameters and observed channels (seed 000 eq. 62), and which
extra channel would identify what the given ones cannot."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from ._parametrisation import PARAMETERS, FreeParameters, Parametrisation
from ._shooting import STATE_SIZE, Layout, residuals_and_jacobian, samples_of
from ._telemetry import CHANNELS

STATE_LABELS = [f"{name}0[{i}]" for name in ("attitude", "omega", "q", "nu") for i in range(3)]


def _fisher(J, labels, D, rtol):
    """Rank, singular values, null directions and the covariance of the physical values (delta
    method, Jacobian ``D`` of values w.r.t. the unknowns) from the whitened Jacobian ``J``. The
    columns are scaled to unit norm first, so that the rank does not depend on units (a column
    ≤ 1e-12 of the largest is taken as zero: an unknown the data do not see)."""
    J = np.asarray(J)
    norms = np.linalg.norm(J, axis=0)
    seen = norms > 1e-12 * np.max(norms)  # a column at round-off level is a zero column
    c = np.where(seen, norms, 1.0)
    _, s, vt = np.linalg.svd(np.where(seen, J / c, 0.0), full_matrices=True)
    s = np.concatenate([s, np.zeros(J.shape[1] - s.size)])
    rank = int(np.sum(s > rtol * s[0]))
    null = vt[rank:]
    cov_z = ((vt[:rank].T / s[:rank] ** 2) @ vt[:rank]) / np.outer(c, c)
    cov = D @ cov_z @ D.T
    identifiable = np.linalg.norm(null, axis=0) <= 1e-4
    std = np.where(identifiable, np.sqrt(np.maximum(np.diag(cov), 0.0)), np.inf)
    report = {
        "rank": rank,
        "parameters": len(labels),
        "singular_values": [float(x) for x in s],
        "identifiable": [k for k, ok in zip(labels, identifiable) if ok],
        "not_identifiable": [k for k, ok in zip(labels, identifiable) if not ok],
        "null_directions": [_readable(v / c, labels) for v in _echelon(null)],
    }
    return report, cov, std


def _echelon(null):
    """A basis of the null space in reduced row echelon form (pivots on the largest entries):
    each direction moves one unknown by 1 and only non-pivot unknowns besides."""
    basis = np.array(null, dtype=float)
    pivots = []
    for row in range(basis.shape[0]):
        free = [c for c in range(basis.shape[1]) if c not in pivots]
        col = free[int(np.argmax(np.abs(basis[row, free])))]
        pivots.append(col)
        basis[row] /= basis[row, col]
        for other in range(basis.shape[0]):
            if other != row:
                basis[other] -= basis[other, col] * basis[row]
    return basis


def _readable(v, labels):
    v = v / np.max(np.abs(v))
    return {labels[i]: round(float(v[i]), 4) for i in np.argsort(-np.abs(v)) if abs(v[i]) > 1e-4}


def observed_rows(mask, m, extra=()):
    """Rows of the residual vector (see ``_shooting.observation_residuals``) of the components
    that ``mask`` (channel → (m, 3)) observes and every component of the channels ``extra``."""
    out = []
    for i, c in enumerate(CHANNELS):
        keep = np.ones((m, 3), bool) if c in extra else np.asarray(mask[c]) > 0 if c in mask else np.zeros((m, 3), bool)
        out.append(i * 3 * m + np.flatnonzero(keep.ravel()))
    return np.concatenate(out)


POORLY_DETERMINED = 1.0  # σ in θ: a factor e for the positive parameters, 1 cm for the offset


def channel_report(J, mask, labels, z_labels, rtol):
    """From the Jacobian ``J`` of the residuals of every channel at every sample (columns: the
    free parameters ``labels`` in θ, then states): which unknowns the components in ``mask``
    leave undetermined — exactly (a null direction of J) or in practice (σ in θ above
    ``POORLY_DETERMINED``: a factor e for a positive parameter, 1 cm for the offset) — and, for
    each channel not fully observed, which of them adding it would determine."""
    m = next(iter(mask.values())).shape[0]

    def undetermined(extra=()):
        rows = observed_rows(mask, m, extra)
        report, _, std = _fisher(J[rows], z_labels, np.eye(len(z_labels)), rtol)
        poor = [k for k, s in zip(z_labels, std) if np.isfinite(s) and s > POORLY_DETERMINED and k in labels]
        return report, poor, std

    given, poor, std = undetermined()
    lost = given["not_identifiable"]
    out = {
        "observed_components": {c: [int(x) for x in np.asarray(mk).sum(0)] for c, mk in mask.items() if np.any(np.asarray(mk))},
        "not_identifiable": [k for k in lost if k in labels],
        "states_not_identifiable": [k for k in lost if k not in labels],
        "poorly_determined": {k: float(s) for k, s in zip(z_labels, std) if k in poor},
        "null_directions": [d for d in given["null_directions"] if any(k in labels for k in d)],
        "adding_a_channel": {},
    }
    for c in CHANNELS:
        if c in mask and np.all(np.asarray(mask[c]) > 0):
            continue
        report, poor_now, _ = undetermined((c,))
        now = report["not_identifiable"]
        out["adding_a_channel"][c] = {
            "identifies": [k for k in lost if k not in now],
            "determines": [k for k in poor if k not in poor_now and k not in now],
            "still_undetermined": [k for k in now if k in labels] + poor_now,
        }
    return out


def identifiability(
    model,
    x0,
    data,
    *,
    h=None,
    known=((), ("mass",), ("mass", "buoyancy")),
    estimate_state=True,
    matrices="diagonal",
    tau="cayley",
    order=1,
    rtol=1e-7,
):
    """What ``data``'s sampling identifies at ``model`` from the initial state ``x0``: for each
    set of ``known`` parameters (the others free, and the initial state too with
    ``estimate_state``, as :func:`~vi_jax.fitting.fit` does) and for
    each given channel alone and all of them together, the rank of the whitened Jacobian
    (singular values below ``rtol``·s_max of the column-normalised Jacobian count as zero), the
    identifiable parameters (orthogonal to every null direction), the null directions (log
    coordinates for the positive parameters) and standard deviations at the data's noise
    levels."""
    from ._fit import DEFAULT_H, as_telemetry
    from ._observations import Observations

    telemetry = as_telemetry(data)
    h = (data.h if isinstance(data, Observations) else DEFAULT_H) if h is None else float(h)
    model_of = FreeParameters(Parametrisation(model, matrices), model, PARAMETERS)
    t = np.asarray(telemetry.t)
    layout = Layout(t, t[0], h, 1, max(1, math.ceil((t[-1] - t[0]) / h - 1e-9)))
    state = jnp.concatenate([jnp.zeros(3), x0.xi, x0.q, x0.g.T @ x0.qdot])[None]
    _, J, ok, _ = residuals_and_jacobian(
        model_of.initial(), state, x0.g[None], model_of, layout, samples_of(telemetry), jnp.asarray(0.0), "squared", tau, order
    )
    if not bool(ok):
        raise ValueError("model: the simulation of the observed interval fails at these parameters")
    J = np.asarray(J)
    all_labels = model_of.labels()
    D_all = np.asarray(jax.jacfwd(lambda th: model_of.param.values(model_of(th)))(model_of.initial()))
    out = {}
    channel_sets = [(c,) for c in telemetry.channels] + ([telemetry.channels] if len(telemetry.channels) > 1 else [])
    for fixed in known:
        cols = Parametrisation(model, matrices).indices(tuple(n for n in PARAMETERS if n not in fixed))
        cols_z = np.concatenate([cols, len(all_labels) + np.arange(STATE_SIZE if estimate_state else 0)])
        names = [all_labels[i] for i in cols]
        D = np.eye(cols_z.size)
        D[: cols.size, : cols.size] = D_all[np.ix_(cols, cols)]
        for observed in channel_sets:
            rows = observed_rows({c: telemetry.mask[c] for c in observed}, t.size)
            report, _, std = _fisher(J[np.ix_(rows, cols_z)], (names + STATE_LABELS)[: cols_z.size], D, rtol)
            report["identifiable"] = [k for k in report["identifiable"] if k in names]
            report["not_identifiable"] = [k for k in report["not_identifiable"] if k in names]
            report["parameters"] = len(names)
            report["std"] = {k: (float(v) if math.isfinite(v) else None) for k, v in zip(names, std)}
            out[f"known: {', '.join(fixed) or 'none'}; observed: {' + '.join(observed)}"] = report
    return out
