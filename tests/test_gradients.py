"""Gradients through the implicit steps (implicit-function theorem) against central finite
differences: physical parameters, initial state and step size; finite at ω = 0."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj

N_STEPS = 100
H = 0.02


def final_state_loss(sol):
    return jnp.sum(sol.q[-1] ** 2) + jnp.sum(sol.R[-1] * jnp.arange(9.0).reshape(3, 3)) + jnp.sum(sol.omega[-1])


def central_difference(f, x, direction, eps):
    return (f(x + eps * direction) - f(x - eps * direction)) / (2 * eps)


def assert_directional_derivative(f, x, grad, direction, eps):
    exact = float(jnp.vdot(grad, direction))
    approx = float(central_difference(f, x, direction, eps))
    assert abs(exact - approx) <= 1e-6 * max(abs(exact), 1e-8), (exact, approx)


PARAMETERS = ["mass", "added_mass", "inertia", "buoyancy", "buoyancy_offset"]


@pytest.mark.parametrize("tau, omega0", [("cayley", None), ("exp", None), ("exp", (0.0, 0.0, 0.0)), ("cayley", (0.0, 0.0, 0.0))])
def test_parameter_gradients_match_finite_differences(tau, omega0):
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state(omega0=None if omega0 is None else jnp.asarray(omega0))

    def loss(m):
        return final_state_loss(vj.simulate(m, x0, H, N_STEPS, tau=tau))

    grads = eqx.filter_grad(loss)(model)
    rng = np.random.default_rng(0)
    for name in PARAMETERS:
        value = getattr(model, name)
        g = getattr(grads, name)
        assert np.all(np.isfinite(g)), name
        direction = jnp.asarray(rng.normal(size=value.shape))
        if value.ndim == 2:
            direction = direction + direction.T  # stay symmetric
        eps = 1e-6 * float(jnp.max(jnp.abs(value)))

        def along(x, name=name):
            return loss(eqx.tree_at(lambda m: getattr(m, name), model, x))

        assert_directional_derivative(along, value, g, direction, eps)


def test_initial_state_and_step_size_gradients():
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()

    def loss(v0, omega0, h):
        state = vj.State(g=x0.g, xi=omega0, q=x0.q, qdot=v0)
        return final_state_loss(vj.simulate(model, state, h, N_STEPS))

    g_v, g_w, g_h = jax.grad(loss, argnums=(0, 1, 2))(x0.qdot, x0.xi, jnp.asarray(H))
    d = jnp.array([0.3, -0.5, 0.8])
    assert_directional_derivative(lambda v: loss(v, x0.xi, H), x0.qdot, g_v, d, 1e-6)
    assert_directional_derivative(lambda w: loss(x0.qdot, w, H), x0.xi, g_w, d, 1e-6)
    assert_directional_derivative(lambda h: loss(x0.qdot, x0.xi, h), jnp.asarray(H), g_h, jnp.asarray(1.0), 1e-7)


def test_implicit_gradient_equals_unrolled_newton():
    """The implicit-function gradient equals differentiating through the Newton iterations."""
    from vi_jax.discrete import dep_step, legendre_initial_state
    from vi_jax.lie import Cayley

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()

    def unrolled_step(m):
        state = legendre_initial_state(m, x0.g, x0.xi, x0.q, x0.qdot)
        n = m.body_configuration(state.g, state.q)
        a = m.body_advected(state.g)
        from vi_jax.discrete._dep import _join, discrete_momenta

        def F(z):
            (M, P), _, _ = discrete_momenta(m, Cayley(), "left", H, z, n, a)
            return _join(M, P) - _join(state.M, state.P)

        # eight Newton iterations, differentiated through (a rolled loop: one copy to compile)
        z = jax.lax.fori_loop(0, 8, lambda _, z: z - jnp.linalg.solve(jax.jacfwd(F)(z), F(z)), state.z)
        return jnp.sum(z**2)

    def implicit_step(m):
        state = legendre_initial_state(m, x0.g, x0.xi, x0.q, x0.qdot)
        new, _ = dep_step(m, Cayley(), "left", jnp.asarray(H), state, rtol=1e-14, max_iterations=20)
        return jnp.sum(new.z**2)

    g1 = eqx.filter_jit(eqx.filter_grad(unrolled_step))(model)
    g2 = eqx.filter_jit(eqx.filter_grad(implicit_step))(model)
    for name in PARAMETERS:
        a, b = getattr(g1, name), getattr(g2, name)
        assert float(jnp.max(jnp.abs(a - b))) <= 1e-10 * max(float(jnp.max(jnp.abs(a))), 1.0), name


@pytest.mark.parametrize("scheme", ["dep", "splitting"])
def test_a_lagrangian_closing_over_a_differentiated_parameter(scheme):
    """A user's Lagrangian may close over the value being differentiated (the scene's arrays are
    then concrete while a transformation traces the call): ``vj.simulate`` takes its traced
    path, and the gradient equals the one with the same value passed as a parameter, and
    central finite differences (step 1e-5: error O(1e-10) against a gradient of O(1))."""
    x0 = vj.State(jnp.eye(3), jnp.array([0.3, 1.0, 0.2]))
    weights = jnp.arange(9.0).reshape(3, 3)

    def loss(c, closed_over):
        def lagrangian(xi, n, nu, a, params):
            inertia = jnp.array([1.0, 2.0, params["c"] if not closed_over else c])
            return 0.5 * jnp.sum(inertia * xi**2)

        system = vj.System(vj.lie.SO3(), lagrangian, {"c": jnp.asarray(3.0) if closed_over else c})
        sol = vj.simulate(system, x0, 0.01, 50, save_every=5, scheme=scheme)
        return jnp.sum(sol.g[-1] * weights)

    c = jnp.asarray(3.0)
    closed = jax.grad(lambda c: loss(c, True))(c)
    passed = jax.grad(lambda c: loss(c, False))(c)
    fd = (loss(c + 1e-5, False) - loss(c - 1e-5, False)) / 2e-5
    np.testing.assert_allclose(closed, passed, rtol=1e-12)
    np.testing.assert_allclose(closed, fd, rtol=1e-6)
    assert abs(float(closed)) > 1e-3
