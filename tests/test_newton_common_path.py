"""A concrete ``vj.simulate`` runs first the program without Newton's full iterations (one Newton
step and the chord steps), and the program with them only when a step needs them: either way
every step equals the same step of the traced program, which always holds them."""

import jax
import numpy as np
import pytest

import vi_jax as vj

EPS = np.finfo(np.float64).eps


@pytest.mark.parametrize("h, needs_full_iterations", [(0.005, False), (0.02, True)])
def test_concrete_run_equals_the_traced_run(h, needs_full_iterations):
    """The heavy top converges in the common path at h = 0.005 and needs full iterations at
    h = 0.02: the concrete run equals the jitted one (static scan, full iterations compiled)
    to Newton's tolerance (64ε per step, a √n random walk, a factor 4 for its tail)."""
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    n_steps = 200
    concrete = vj.simulate(model, x0, h, n_steps)
    traced = jax.jit(lambda x: vj.simulate(model, x, h, n_steps))(x0)
    iterations = np.asarray(concrete.newton_iterations)
    assert (iterations.max() > 1 + vj.solvers.CHORD_ITERATIONS) == needs_full_iterations
    np.testing.assert_array_equal(iterations, np.asarray(traced.newton_iterations))
    assert bool(concrete.succeeded)
    bound = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "xi", "M", "energy"):
        ours, theirs = np.asarray(getattr(concrete, field)), np.asarray(getattr(traced, field))
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field


def test_a_failing_run_reports_the_full_programs_failure():
    """At h = 0.11 with at most 5 iterations the heavy top's steps need full iterations and one
    fails after 11 that succeeded: reported where the traced run reports it, with its codes."""
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    options = dict(throw=False, max_newton_iterations=5)
    concrete = vj.simulate(model, x0, 0.11, 20, **options)
    traced = jax.jit(lambda x: vj.simulate(model, x, 0.11, 20, **options))(x0)
    result = np.asarray(concrete.result)
    assert np.all(result[:12] == vj.solvers.SUCCESS) and result[12] == vj.solvers.MAX_ITERATIONS
    np.testing.assert_array_equal(result, np.asarray(traced.result))
    np.testing.assert_array_equal(np.asarray(concrete.newton_iterations), np.asarray(traced.newton_iterations))
