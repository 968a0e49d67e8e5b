"""The free rigid body and the heavy top on SO(n) through the generic engine: SO(3) via SOn(3)
agrees with the SO3 classes, and on SO(3), SO(4) the Kelvin–Noether quantities are conserved to
round-off, g stays on the group and the energy stays bounded."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.lie import SO3, SOn

# SOn(3) coordinates (x01, x02, x12) = (x3, −x2, x1) of the SO3 cross-product convention.
SO3_TO_SON3 = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
N = 1000  # steps of every run (order 2): runs of equal structure share one compilation
EPS = np.finfo(np.float64).eps


def separation(rate, t, scale):
    """Bound on the distance after N steps (time t) of two roundings of the same map (here SO3's
    closed forms against SOn(3)'s generic ones): their invariants part like a random walk
    (√N·ε), which the flow shears into a phase error growing like rate·t, rate = |ω|."""
    return 10 * EPS * np.sqrt(N) * (1 + rate * t) * scale


def so3_to_son3(x):
    return np.asarray(x) @ SO3_TO_SON3.T


@functools.cache
def run(model, n):
    """(system, solution): the rigid body and the heavy top on SO(n) (one compile each)."""
    if model == "rigid_body":
        system = vj.models.RigidBody(group=SOn(n), mass_matrix=np.linspace(0.6, 0.1, n))
        xi0 = 0.8 * np.cos(np.arange(system.group.dim) + 1.0)
        h = 0.1
    else:
        system = vj.models.HeavyTop(group=SOn(n), center_of_mass=np.r_[0.1, np.zeros(n - 2), 0.5])
        xi0 = np.r_[6.0, 0.5 * np.cos(np.arange(system.group.dim - 1))]
        h = 0.01
    return system, vj.simulate(system, system.initial_state(omega0=xi0), h, N, order=2)


def test_coordinate_map_and_default_bodies():
    """hat_SOn(3)(Px) = hat_SO3(x); the SO3 inertia (I₁, I₂, I₃) is the SOn(3) mass matrix
    J_i = tr(I)/2 − I_i; HeavyTop(group=SOn(3)) defaults to the SO3 default top."""
    x = jnp.array([0.3, -1.2, 0.7])
    np.testing.assert_array_equal(SOn(3).hat(so3_to_son3(x)), SO3().hat(x))
    inertia = np.array([0.5, 0.6, 1.0])
    body = vj.models.RigidBody(group=SOn(3), mass_matrix=inertia.sum() / 2 - inertia)
    np.testing.assert_allclose(body.inertia, SO3_TO_SON3 @ np.diag(inertia) @ SO3_TO_SON3.T, atol=1e-15)
    np.testing.assert_allclose(
        vj.models.RigidBody(mass_matrix=inertia.sum() / 2 - inertia).inertia, np.diag(inertia), atol=1e-15
    )
    top, top3 = vj.models.HeavyTop(), vj.models.HeavyTop(group=SOn(3))
    np.testing.assert_allclose(top3.inertia, SO3_TO_SON3 @ top.inertia @ SO3_TO_SON3.T, atol=1e-15)
    np.testing.assert_array_equal(top3.center_of_mass, top.center_of_mass)
    x0, x03 = top.initial_state(), top3.initial_state()
    np.testing.assert_array_equal(x03.g, x0.g)
    np.testing.assert_allclose(x03.xi, so3_to_son3(x0.xi), atol=1e-15)


@pytest.mark.parametrize("model", ["rigid_body", "heavy_top"])
def test_son3_agrees_with_so3(model):
    """The same free body and heavy top through SO3 and through SOn(3): identical g, and
    velocities, momenta, energy and Kelvin–Noether quantities after mapping coordinates."""
    if model == "rigid_body":
        inertia = np.array([0.5, 0.6, 1.0])
        so3 = vj.models.RigidBody(inertia=inertia)
        son3 = vj.models.RigidBody(group=SOn(3), mass_matrix=inertia.sum() / 2 - inertia)
        omega, h = np.array([1.0, 0.5, -0.3]), 0.1
    else:
        so3, son3, omega, h = vj.models.HeavyTop(), vj.models.HeavyTop(group=SOn(3)), np.array([0.3, -0.2, 6.0]), 0.01
    a = vj.simulate(so3, so3.initial_state(omega0=omega), h, N, order=2)
    b = vj.simulate(son3, son3.initial_state(omega0=so3_to_son3(omega)), h, N, order=2)
    rate, t = float(np.max(np.abs(a.xi))), N * h
    for ours, theirs in ((b.g, a.g), (b.xi, so3_to_son3(a.xi)), (b.M, so3_to_son3(a.M))):
        bound = separation(rate, t, float(np.max(np.abs(theirs))))  # measured ≤ 0.05 of it
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=bound)
    np.testing.assert_allclose(b.energy, a.energy, rtol=1e-12)
    kn_a, kn_b = np.asarray(a.kelvin_noether), np.asarray(b.kelvin_noether)
    if model == "rigid_body":  # the spatial momentum, mapped like the coordinates
        np.testing.assert_allclose(kn_b, so3_to_son3(kn_a), rtol=0, atol=1e-11)
    else:  # the vertical component, up to the sign of the isotropy basis
        np.testing.assert_allclose(np.abs(kn_b), np.abs(kn_a), rtol=0, atol=1e-11)


@pytest.mark.parametrize("model", ["rigid_body", "heavy_top"])
@pytest.mark.parametrize("n", [3, 4])
def test_son_conservation(model, n):
    """Kelvin–Noether (spatial momentum; for the top its so(n−1) isotropy part) to round-off
    relative to kelvin_noether_scale; g ∈ SO(n); energy bounded; Newton converged."""
    system, sol = run(model, n)
    kn = np.asarray(sol.kelvin_noether).reshape(N + 1, -1)
    expected_columns = system.group.dim if model == "rigid_body" else (n - 1) * (n - 2) // 2
    assert kn.shape[1] == expected_columns
    scale = np.max(np.asarray(sol.kelvin_noether_scale))
    assert np.max(np.abs(kn - kn[0])) <= 1e-13 * scale
    assert float(jnp.max(vj.group_constraint_residual(system, sol.g))) <= 1e-12
    energy = np.asarray(sol.energy)
    assert np.max(np.abs(energy / energy[0] - 1)) <= 2e-3
    assert np.max(np.asarray(sol.newton_residual)) <= 1e-12
    if model == "heavy_top":
        # Control: spatial momentum outside the isotropy algebra of e_n is not conserved.
        spatial = jax.vmap(system.group.Ad_dual_inv)(sol.g, sol.M)
        assert float(jnp.max(jnp.abs(spatial - spatial[0]))) > 1e-2 * scale
    else:
        # The Casimir |M| of the free body is conserved too.
        norms = np.linalg.norm(np.asarray(sol.M), axis=1)
        assert np.max(np.abs(norms / norms[0] - 1)) <= 1e-13


@pytest.mark.parametrize(
    "build,argument",
    [
        (lambda: vj.models.RigidBody(group=SOn(2)), "group"),
        (lambda: vj.models.HeavyTop(group=vj.lie.SE3()), "group"),
        (lambda: vj.models.RigidBody((1.0, 1.0, 1.0), mass_matrix=(1.0, 1.0, 1.0)), "inertia, mass_matrix"),
        (lambda: vj.models.RigidBody(group=SOn(4), mass_matrix=(1.0, 1.0, 1.0)), "mass_matrix"),
        (lambda: vj.models.RigidBody(group=SOn(4), mass_matrix=(1.0, -2.0, 0.5, 0.5)), "inertia from mass_matrix"),
        (lambda: vj.models.RigidBody(group=SOn(3), mass_matrix=[[1.0, 0.2, 0], [0, 1, 0], [0, 0, 1]]), "mass_matrix"),
        (lambda: vj.models.RigidBody(group=SOn(4), inertia=(1.0, 2.0, 3.0)), "inertia"),
        (lambda: vj.models.HeavyTop(group=SOn(4), center_of_mass=(0.0, 0.0, 1.0)), "center_of_mass"),
        (lambda: vj.models.RigidBody(group=SOn(4)).initial_state(omega0=(1.0, 2.0, 3.0)), "omega0"),
        (lambda: vj.models.HeavyTop(group=SOn(4)).initial_state(R0=np.eye(3)), "R0"),
    ],
)
def test_invalid_input_names_argument(build, argument):
    with pytest.raises(ValueError, match=argument):
        build()
