"""Free rigid body and heavy top through the generic engine (no V*/Q; V* only)."""

import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj

EPS = np.finfo(np.float64).eps


def round_off(n, scale=1.0):
    """Bound on the drift of a quantity that the scheme conserves exactly, after n steps: each
    step rounds it by a few ε·scale, uncorrelated from step to step, so the errors add like a
    random walk: 30·√n·ε·scale covers a 6ε step at 5σ (measured ≤ 2.7·√n·ε across the suite). A
    bias of one ε per step would cross it after 900 steps."""
    return 30 * np.sqrt(n) * EPS * scale


@pytest.mark.parametrize("tau", ["cayley", "exp"])
@pytest.mark.parametrize("order", [1, 2])
def test_free_rigid_body_momenta_conserved(tau, order):
    """Spatial angular momentum R_k M_k and |M_k| (the discrete Legendre momentum μ̃) are
    conserved to round-off; |IΩ| at the nodes is not (it moves by O(h²), seed 002 spec)."""
    body = vj.models.RigidBody(inertia=(0.5, 0.6, 1.0))
    sol = vj.simulate(body, body.initial_state(omega0=(1.0, 0.5, -0.3)), 0.1, 5000, tau=tau, order=order)
    spatial = np.asarray(sol.kelvin_noether)
    assert spatial.shape == (5001, 3)
    drift = np.max(np.abs(spatial - spatial[0])) / np.linalg.norm(spatial[0])
    assert drift <= round_off(5000)  # measured 0.9·√n·ε
    norms = np.linalg.norm(np.asarray(sol.M), axis=1)
    assert np.max(np.abs(norms / norms[0] - 1)) <= round_off(5000)
    assert float(jnp.max(vj.group_constraint_residual(body, sol.R))) <= 1e-12


def test_free_rigid_body_at_rest_is_exact():
    body = vj.models.RigidBody()
    sol = vj.simulate(body, body.initial_state(omega0=(0.0, 0.0, 0.0)), 0.1, 10, tau="exp")
    np.testing.assert_array_equal(np.asarray(sol.R[-1]), np.eye(3))
    assert np.all(np.asarray(sol.omega) == 0)


@pytest.mark.parametrize("tau", ["cayley", "exp"])
def test_heavy_top_vertical_momentum_conserved(tau):
    """Only the component of spatial angular momentum along gravity is a Kelvin–Noether
    quantity for the heavy top (isotropy algebra of e₃); energy stays bounded."""
    top = vj.models.HeavyTop()
    sol = vj.simulate(top, top.initial_state(), 0.01, 20_000, tau=tau, order=2)
    vertical = np.asarray(sol.kelvin_noether)
    assert vertical.shape == (20_001,)
    scale = np.max(np.asarray(sol.kelvin_noether_scale))
    assert np.max(np.abs(vertical - vertical[0])) <= round_off(20_000, scale)  # measured 1.4·√n·ε
    energy = np.asarray(sol.energy)
    assert np.max(np.abs(energy / energy[0] - 1)) <= 1e-3
    # Control: the horizontal spatial momentum is not conserved (gravity exerts a torque).
    spatial = np.einsum("kij,kj->ki", np.asarray(sol.R), np.asarray(sol.M))
    assert np.max(np.abs(spatial[:, 0] - spatial[0, 0])) > 1e-2
