"""Small ``dot_general``s replayed as multiply-and-sum in a single trajectory's step
(vi_jax/lie/_small.py: ``fused_products``), whatever products the user's Lagrangian writes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend import core as jcore

import vi_jax as vj
from vi_jax.lie import _small

# (lhs shape, rhs shape, ((lhs contracting, rhs contracting), (lhs batch, rhs batch)))
CASES = [
    ((3,), (3,), (((0,), (0,)), ((), ()))),  # x · y
    ((3, 3), (3,), (((1,), (0,)), ((), ()))),  # A x
    ((3,), (3, 3), (((0,), (0,)), ((), ()))),  # xᵀ A
    ((2, 3), (3, 4), (((1,), (0,)), ((), ()))),  # A B
    ((3, 2), (3, 4), (((0,), (0,)), ((), ()))),  # Aᵀ B
    ((5, 2, 3), (5, 3, 4), (((2,), (1,)), ((0,), (0,)))),  # batched A B
    ((6, 3), (3, 3), (((1,), (1,)), ((), ()))),  # A Bᵀ
    ((2, 3, 4), (3, 4), (((1, 2), (0, 1)), ((), ()))),  # two contracted axes
    ((3,), (4,), (((), ()), ((), ()))),  # outer product
]


@pytest.mark.parametrize("lhs_shape, rhs_shape, dims", CASES)
def test_multiply_and_sum_is_dot_general(lhs_shape, rhs_shape, dims):
    rng = np.random.default_rng(0)
    lhs, rhs = rng.normal(size=lhs_shape), rng.normal(size=rhs_shape)
    expected = jax.lax.dot_general(lhs, rhs, dims, precision="highest")
    got = _small._dot_as_sum(jnp.asarray(lhs), jnp.asarray(rhs), dimension_numbers=dims)
    assert got.shape == expected.shape
    # Both sum the same k products, in possibly different orders: within k ulps of Σ|products|.
    k = int(np.prod([lhs_shape[d] for d in dims[0][0]]))
    bound = k * np.finfo(np.float64).eps * jax.lax.dot_general(np.abs(lhs), np.abs(rhs), dims)
    assert np.all(np.abs(got - expected) <= bound)


def test_a_traced_function_replays_with_the_same_values():
    J = jnp.diag(jnp.array([1.0, 2.0, 3.0])) + 0.1

    def energy(state):
        xi, nu = state["xi"], state["nu"]
        return {"e": 0.5 * xi @ J @ xi + nu @ nu, "p": J @ xi}

    state = {"xi": jnp.array([0.3, -0.2, 0.5]), "nu": jnp.array([1.0, 2.0])}
    got, expected = _small.with_fused_products(energy)(state), energy(state)
    for key in expected:
        np.testing.assert_allclose(got[key], expected[key], rtol=4 * np.finfo(np.float64).eps)
    closed = jax.make_jaxpr(_small.with_fused_products(energy))(state)
    assert not _dots(closed.jaxpr)


def _dots(jaxpr):
    """The ``dot_general`` equations of ``jaxpr`` and of every jaxpr inside it."""
    found = [e for e in jaxpr.eqns if e.primitive.name == "dot_general"]
    for e in jaxpr.eqns:
        for sub in jcore.jaxprs_in_params(e.params):
            found += _dots(sub)
    return found


def _scan_bodies(jaxpr):
    """The bodies of the ``scan`` loops in ``jaxpr``: the steps, their blocks and node loops
    (the node diagnostics run after the loops, on all nodes at once)."""
    bodies = []
    for e in jaxpr.eqns:
        subs = list(jcore.jaxprs_in_params(e.params))
        if e.primitive.name == "scan":
            bodies += subs
        for sub in subs:
            bodies += _scan_bodies(sub)
    return bodies


def test_the_vehicle_step_holds_no_small_dot():
    """The vehicle's Lagrangian writes ``ν @ M @ ν``, ``ξ @ J @ ξ``, ``n @ a``: its step (the
    Newton residual, its Jacobian and the update) holds none of them as a dot."""
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    closed = jax.make_jaxpr(lambda m, x: vj.simulate(m, x, 0.01, 10, throw=False))(model, x0)
    steps = _scan_bodies(closed.jaxpr)
    assert steps and all(not _dots(step) for step in steps)


def test_batched_products_keep_the_dots():
    """Under ``batched_products`` (``vj.ensemble``'s ``vmap`` path on CPU, where batched dots
    are faster) the replay keeps them."""
    closed = jax.make_jaxpr(lambda x: x @ x)(jnp.ones(3))
    with _small.batched_products():
        replayed = jax.make_jaxpr(_small.fused_products(closed))(jnp.ones(3))
    assert _dots(replayed.jaxpr)


def test_a_vmapped_simulate_keeps_its_dots():
    """``jax.vmap`` of ``vj.simulate`` (and ``vj.ensemble(method="vmap")``) batch the step:
    there batched dots are faster, so the replay keeps them."""
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    members = vj.vary(x0, xi=x0.xi + jnp.linspace(0.0, 0.1, 4)[:, None])
    closed = jax.make_jaxpr(lambda s: jax.vmap(lambda x: vj.simulate(model, x, 0.01, 10, throw=False).q)(s))(members)
    assert any(_dots(step) for step in _scan_bodies(closed.jaxpr))
