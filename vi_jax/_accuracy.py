"""A warning for runs whose own diagnostics say they are meaningless.

Every scene the engines integrate is conservative, so the energy error along a run measures how
far the numerical solution is from the dynamics. Past ``MEANINGLESS_ENERGY_ERROR`` (half of
|E₀|, the stability study's "bounded" criterion; its "accurate" one is 1e-3, docs/stability.md)
a run no longer resembles the motion it approximates, and the caller is told, once per call, with
a pointer to the safe-step table. Sound runs at a scheme's stability limit stay below it (the
leapfrog wave equation at Courant number 1: 0.3). Non-finite values after a failed step are left
to the failure report (``result`` codes). Silent on traced values (inside ``jit``).
"""

import warnings

import numpy as np

from . import _validation as val

MEANINGLESS_ENERGY_ERROR = 0.5


class AccuracyWarning(RuntimeWarning):
    """A run finished, but its energy error says its result does not represent the dynamics."""


def energy_error(energy, axis=-1):
    """max |E − E₀| / |E₀| along ``axis`` (the time axis) over the finite values (|E₀| = 0:
    relative to max |E|)."""
    e = np.asarray(energy, dtype=float)
    finite = np.isfinite(e)
    e0 = np.take(e, [0], axis=axis)
    scale = np.where(e0 != 0, np.abs(e0), np.max(np.abs(np.where(finite, e, 0.0)), axis=axis, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.abs(e - e0) / np.where(scale > 0, scale, 1.0)
    return np.max(np.where(finite, rel, 0.0), axis=axis)


def warn_if_meaningless(energy, where: str, *, members: bool = False):
    """Warn when the relative energy error of a concrete run exceeds the threshold (for an
    ensemble, ``members=True``: the leading axis is the member, and the warning counts them)."""
    if not val.is_concrete(energy) or np.size(energy) == 0:
        return
    err = energy_error(energy)
    bad = np.asarray(err > MEANINGLESS_ENERGY_ERROR)
    if not np.any(bad):
        return
    who = f"{int(bad.sum())} of {bad.size} members: " if members else ""
    warnings.warn(
        f"{where}: {who}the relative energy error reached {float(np.max(err)):.3g} (> {MEANINGLESS_ENERGY_ERROR:g}); "
        "the step is too large for this motion and the result does not represent the dynamics. "
        "Reduce h: see the safe-step table in the README's Stability section (docs/stability.md).",
        AccuracyWarning,
        stacklevel=3,
    )
