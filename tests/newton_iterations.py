"""Newton's iteration counts of a concrete ``vj.simulate`` against a traced run's or an
ensemble's. A concrete call's loops roll Newton's iterations
(``vi_jax.solvers._newton.rolled_iterations``) and check each iterate, stopping at the first
converged one; traced steps, and ensemble steps whose chord steps are not checked, run one Newton
step and the chord steps unrolled, then check once. The iterates are the same up to where the
rolled loop stops. Ensemble steps with checked chord steps stop at the first converged iterate
too."""

import numpy as np

import vi_jax as vj

COMMON_PATH = 1 + vj.solvers.CHORD_ITERATIONS


def assert_rolled_iterations_match(rolled, unrolled):
    """Per step (or per node: the most over its steps): where the unrolled steps needed Newton's
    full iterations the rolled ones took the same (no chord iterate converged); elsewhere they
    stopped at the first converged (or non-finite) iterate, after 1 … ``COMMON_PATH``; 0 in
    the rows of no step (the initial state)."""
    rolled, unrolled = np.asarray(rolled), np.asarray(unrolled)
    assert rolled.shape == unrolled.shape
    full = unrolled > COMMON_PATH
    np.testing.assert_array_equal(rolled[full], unrolled[full])
    assert np.all(np.where(unrolled == 0, rolled == 0, (rolled >= 1) & (rolled <= unrolled))), (rolled, unrolled)


def assert_first_converged_iterations_match(a, b):
    """Per step (or per node) of two runs that each stop at the first converged iterate (a
    concrete ``vj.simulate``, an ensemble with checked chord steps): the same iterates, each
    checked against the tolerance, so the counts agree but where a residual lies within
    round-off of the tolerance (its two evaluations round differently): there one run takes one
    more iteration; 0 in the rows of no step in both."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    np.testing.assert_array_equal(a == 0, b == 0)
    assert np.max(np.abs(a - b)) <= 1, (a, b)


def chords_checked(system, x0, h, tau, order):
    """Whether the generated step checks the chord steps of this ensemble (``x0``: members
    first) by default: its residual costs at least ``CHECK_COST`` operations per member."""
    from vi_jax.engine import _generated_step

    return _generated_step.scene_operations(system, x0, h, tau, order)[0] >= _generated_step.CHECK_COST
