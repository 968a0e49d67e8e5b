"""Newton's rolled iterations (``vi_jax.solvers._newton.rolled_iterations``, what a concrete
``vj.simulate``'s one-kernel loops trace): one loop over the evaluations takes the same iterates
as the unrolled first steps and full iterations, stops at the first converged one, holds each
evaluation once, and lets the vehicle's order-2 loops be one kernel."""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax._src import core
from newton_iterations import COMMON_PATH
from test_one_kernel import one_kernel_calls

import vi_jax as vj
from vi_jax.solvers import _newton as _newton_module

B = jnp.array([0.4, -1.3, 2.2])


def _residual(z):
    """A coupled nonlinear system with a unique root: z + 0.9 sin(Az) = b (the sine's Jacobian
    has norm < 1 against the identity), and the size of its terms as the scale."""
    A = jnp.array([[1.0, 0.5, 0.0], [0.5, 1.0, 0.5], [0.0, 0.5, 1.0]])
    s = 0.9 * jnp.sin(A @ z)
    return z + s - B, jnp.max(jnp.abs(z)) + jnp.max(jnp.abs(s)) + jnp.max(jnp.abs(B))


def _newton(max_iterations, rolled):
    """Newton on :func:`_residual` from a guess, traced rolled or unrolled."""

    def run(z0):
        with _newton_module.rolled_iterations() if rolled else contextlib.nullcontext():
            return _newton_module.newton_root(_residual, z0, rtol=1e-14, max_iterations=max_iterations)

    return run


def _solve(z0, max_iterations, rolled):
    return jax.jit(_newton(max_iterations, rolled))(z0)


@pytest.mark.parametrize("max_iterations", [0, 1, 2, 3, 4, 6, 20])
@pytest.mark.parametrize("start", ["near", "far", "nan"])
def test_rolled_iterations_take_the_same_iterates(max_iterations, start):
    """Near the root the last chord step converges; far from it the full iterations run (and
    with few allowed, fail): the same iterations, result and residual, and the same root to a
    few ulps (the same operations, compiled in another program). A NaN guess stays non-finite:
    the rolled loop stops at its first iterate, the unrolled steps after the chord steps."""
    root = _solve(jnp.zeros(3), 20, rolled=False)[0]
    z0 = {"near": root + 1e-3, "far": jnp.array([3.0, -4.0, 5.0]), "nan": jnp.full(3, jnp.nan)}[start]
    z, stats = _solve(z0, max_iterations, rolled=False)
    z_rolled, stats_rolled = _solve(z0, max_iterations, rolled=True)
    if start == "far" and max_iterations == 20:
        assert int(stats.iterations) > COMMON_PATH  # the full iterations ran
    expected = 1 if start == "nan" else int(stats.iterations)
    assert int(stats_rolled.iterations) == expected
    assert int(stats_rolled.result) == int(stats.result)
    np.testing.assert_allclose(stats_rolled.residual, stats.residual, rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(z_rolled, z, rtol=8 * np.finfo(np.float64).eps, atol=0)


@pytest.mark.parametrize("distance, iterations", [(1e-8, 1), (1e-5, 2)])
def test_rolled_iterations_stop_at_the_first_converged_iterate(distance, iterations):
    """From a guess 1e-8 off the root one Newton step converges (its error ~1e-16), from 1e-5
    one chord step after it (~1e-10 · 1e-5): the rolled loop stops there, where the unrolled
    steps run all the chord steps before their one check. Both succeed, at the same root to
    Newton's tolerance (the final correction follows either's last iterate)."""
    root = _solve(jnp.zeros(3), 20, rolled=False)[0]
    z0 = root + distance * jnp.array([1.0, -1.0, 1.0])
    z, stats = _solve(z0, 20, rolled=False)
    z_rolled, stats_rolled = _solve(z0, 20, rolled=True)
    assert int(stats.iterations) == COMMON_PATH
    assert int(stats_rolled.iterations) == iterations
    assert int(stats.result) == int(stats_rolled.result) == vj.solvers.SUCCESS
    assert float(stats_rolled.residual) <= 1e-14
    np.testing.assert_allclose(z_rolled, z, rtol=0, atol=1e-14 * float(_residual(z)[1]))


def test_rolled_iterations_hold_each_evaluation_once():
    """One sine a residual evaluation: unrolled, the Jacobian's point, three chord points and the
    full iterations' Jacobian hold five; rolled, the residual and its Jacobian one each."""

    def count(jaxpr):  # every call of a nested jaxpr counted (a jaxpr prints once however many call it)
        return sum((eqn.primitive.name == "sin") + sum(map(count, core.jaxprs_in_params(eqn.params))) for eqn in jaxpr.eqns)

    def sines(rolled):
        return count(jax.make_jaxpr(_newton(20, rolled))(jnp.zeros(3)).jaxpr)

    assert sines(rolled=False) == 5
    assert sines(rolled=True) == 2


def test_the_vehicles_order_2_concrete_loops_are_one_kernel():
    """Unrolled, the vehicle's order-2 loop program holds more equations than one kernel takes
    (it keeps the default plan under ``jit``: tests/test_simulate_one_kernel.py); the concrete
    call's, rolled, is one kernel."""
    from vi_jax.discrete import composition_coefficients
    from vi_jax.engine import _simulate
    from vi_jax.engine._advance import traced_composition

    system = vj.models.UnderwaterVehicle()
    count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731
    rule, gammas = composition_coefficients(2)
    options = dict(capacity=16, tau=vj.lie.difference_map("cayley"), rule=rule, gammas=traced_composition(gammas), rtol=1e-14, max_iter=20)
    lowered = _simulate._loop_nodes_jit.lower(system, system.initial_state(), jnp.asarray(0.01), count(12), 1, **options)
    assert one_kernel_calls(lowered.compile().compiled) == 1
