"""Newton's iteration counts of a concrete ``vj.simulate`` against a traced run's or an
ensemble's. A concrete call's loops roll Newton's iterations
(``vi_jax.solvers._newton.rolled_iterations``) and check each iterate, stopping at the first
converged one; traced and ensemble steps run one Newton step and the chord steps unrolled, then
check once. The iterates are the same up to where the rolled loop stops."""

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
