"""Identifiability from the Fisher information: rank, null directions and uncertainties of the
whitened Jacobian, per set of known parameters and observed quantities (seed 000 eq. 62)."""

import math

import jax
import numpy as np

from ._parametrisation import PARAMETERS, Parametrisation
from ._residuals import _jacobian, _weights


def _fisher(J, labels, D, rtol):
    """Rank, singular values, null directions (in θ) and the covariance of the physical values
    (delta method, Jacobian ``D`` of values w.r.t. θ) from the whitened Jacobian ``J``."""
    J = np.asarray(J)
    _, s, vt = np.linalg.svd(J, full_matrices=True)
    s = np.concatenate([s, np.zeros(J.shape[1] - s.size)])
    rank = int(np.sum(s > rtol * s[0]))
    null = vt[rank:]
    cov_theta = (vt[:rank].T / s[:rank] ** 2) @ vt[:rank]
    cov = D @ cov_theta @ D.T
    identifiable = np.linalg.norm(null, axis=0) <= 1e-4
    std = np.where(identifiable, np.sqrt(np.maximum(np.diag(cov), 0.0)), np.inf)
    report = {
        "rank": rank,
        "parameters": len(labels),
        "singular_values": [float(x) for x in s],
        "identifiable": [k for k, ok in zip(labels, identifiable) if ok],
        "not_identifiable": [k for k, ok in zip(labels, identifiable) if not ok],
        "null_directions_theta": [_readable(v, labels) for v in _echelon(null)],
    }
    return report, cov, std


def _echelon(null):
    """A basis of the null space in reduced row echelon form (pivots on the largest entries):
    each direction moves one parameter by 1 and only non-pivot parameters besides."""
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
    return {labels[i]: round(float(v[i]), 4) for i in np.argsort(-np.abs(v)) if abs(v[i]) > 1e-4}


def identifiability(model, x0, obs, *, known=((), ("mass",), ("mass", "buoyancy")), matrices="diagonal", tau="cayley", order=1, rtol=1e-7):
    """What ``obs``'s sampling identifies at ``model``: for each set of ``known`` parameters
    (the others free) and for positions only, attitudes only and both, the rank of the whitened
    Jacobian w.r.t. θ (singular values below ``rtol``·s_max count as zero), the identifiable
    parameters (orthogonal to every null direction), the null directions in θ (log coordinates
    for the positive parameters) and standard deviations at ``obs``'s noise levels."""
    param = Parametrisation(model, matrices)
    theta = param.encode(model)
    r, J, ok = _jacobian(theta, param, x0, obs, _weights(obs), tau, order)
    if not bool(ok):
        raise ValueError("model: the simulation of the observed interval fails at these parameters")
    labels = np.asarray(param.labels())
    D_all = np.asarray(jax.jacfwd(lambda t: param.values(param.decode(t)))(theta))
    out = {}
    for fixed in known:
        cols = param.indices(tuple(n for n in PARAMETERS if n not in fixed))
        for observed in (("position",), ("attitude",), ("position", "attitude")):
            rows = np.asarray(_weights(obs, 1.0, observed)) > 0
            names = [str(k) for k in labels[cols]]
            report, _, std = _fisher(np.asarray(J)[np.ix_(rows, cols)], names, D_all[np.ix_(cols, cols)], rtol)
            report["std"] = {k: (float(v) if math.isfinite(v) else None) for k, v in zip(names, std)}
            out[f"known: {', '.join(fixed) or 'none'}; observed: {' + '.join(observed)}"] = report
    return out
