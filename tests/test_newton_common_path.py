"""A concrete ``vj.simulate`` (rolled iterations, stopping at the first converged iterate) and
``vj.ensemble`` through the generated step (which runs first the program without Newton's full
iterations, and the program with them only when a step needs them): either way every step
equals the same step of the traced program, which always holds them."""

import equinox as eqx
import jax
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.engine import _ensemble

from newton_iterations import COMMON_PATH, assert_rolled_iterations_match

EPS = np.finfo(np.float64).eps


@pytest.mark.parametrize("h, needs_full_iterations", [(0.005, False), (0.02, True)])
def test_concrete_run_equals_the_traced_run(h, needs_full_iterations):
    """The heavy top converges in the common path at h = 0.005 and needs full iterations at
    h = 0.02: the concrete run equals the jitted one (static scan, full iterations compiled)
    to Newton's tolerance (64ε per step, a √n random walk, a factor 4 for its tail), its
    iterations those of :func:`assert_rolled_iterations_match`."""
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    n_steps = 200
    concrete = vj.simulate(model, x0, h, n_steps)
    traced = jax.jit(lambda x: vj.simulate(model, x, h, n_steps))(x0)
    iterations = np.asarray(concrete.newton_iterations)
    assert (iterations.max() > COMMON_PATH) == needs_full_iterations
    assert_rolled_iterations_match(iterations, traced.newton_iterations)
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
    assert_rolled_iterations_match(concrete.newton_iterations, traced.newton_iterations)


@pytest.mark.parametrize("h, needs_full_iterations", [(0.005, False), (0.02, True)])
def test_concrete_ensemble_equals_the_traced_ensemble(h, needs_full_iterations, monkeypatch):
    """The same plan for ``vj.ensemble``'s generated step (four heavy tops): the program without
    full iterations runs first (stopping at the first node where some member needs them), the
    full one only then; the members equal the traced run's (full iterations compiled)."""
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * np.random.default_rng(3).normal(size=(4, 3)))
    n_steps = 100
    programs, run_loop = [], _ensemble._run_loop

    def spy(*args, **options):
        programs.append((options["max_iterations"], options.get("stop_at_failure", False)))
        return run_loop(*args, **options)

    monkeypatch.setattr(_ensemble, "_run_loop", spy)
    concrete = vj.ensemble(model, states, h, n_steps, method="batched")
    traced = eqx.filter_jit(lambda s: vj.ensemble(model, s, h, n_steps, method="batched"))(states)
    assert programs == [(COMMON_PATH, True)] + ([(20, False)] if needs_full_iterations else [])
    iterations = np.asarray(concrete.newton_iterations)
    assert (iterations.max() > COMMON_PATH) == needs_full_iterations
    np.testing.assert_array_equal(iterations, np.asarray(traced.newton_iterations))
    assert bool(np.all(vj.member_converged(concrete)))
    bound = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "xi", "M", "energy"):
        ours, theirs = np.asarray(getattr(concrete, field)), np.asarray(getattr(traced, field))
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field
