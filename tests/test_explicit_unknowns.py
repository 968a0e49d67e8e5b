"""``vj.simulate``'s Newton solves the unknowns with explicit equations first: the vehicle's ν at
order 1 (seed 000 eq. 74, (mI + M_A)ν_k = P_k + h(W − B)a_k: affine in ν alone, with constant
coefficients), and runs Newton on ω only; the trajectory is the one of Newton on every unknown."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.discrete import composition_coefficients
from vi_jax.engine import _advance
from vi_jax.engine._explicit_unknowns import explicit_unknowns
from vi_jax.engine._simulate import _initial
from vi_jax.lie import SO3, LinearAction, difference_map

EPS = np.finfo(np.float64).eps


def _cross_term_system():
    """A ξ–ν cross term 0.4 ξ·ν: P = Mν + 0.4ξ − …, affine with constant coefficients but in ξ
    too, so no row is explicit."""
    J, M = np.diag([2.0, 3.0, 4.0]), np.diag([5.0, 6.0, 7.0])
    lagrangian = lambda xi, n, nu, a, p: 0.5 * xi @ J @ xi + 0.5 * nu @ M @ nu + 0.4 * xi @ nu - p * n @ a  # noqa: E731
    system = vj.System(SO3(), lagrangian, jnp.asarray(9.81), advected=(LinearAction(SO3()), np.eye(3)[2]), additional=LinearAction(SO3()))
    return system, vj.State(jnp.eye(3), jnp.array([0.3, -0.2, 0.5]), jnp.zeros(3), jnp.array([0.1, 0.0, -0.2]))


def _spring_system():
    """A spring −½|n|² with a gyroscopic coupling k n·Aν (A not symmetric) on a trivial
    representation (ρ(g) = I): the P rows are affine in ν alone at every rule (the vehicle's
    are not at the trapezoid's), with coefficients from M, k, A and the step, which differ
    between the sub-step fractions of the trapezoid's compositions (orders 2–6)."""
    J, M = np.diag([2.0, 3.0, 4.0]), np.diag([5.0, 6.0, 7.0])
    A = np.array([[0.0, 1.0, 0.5], [-0.3, 0.2, 0.0], [0.7, 0.0, 0.1]])
    lagrangian = lambda xi, n, nu, a, k: 0.5 * xi @ J @ xi + 0.5 * nu @ M @ nu + k * n @ A @ nu - 0.5 * n @ n  # noqa: E731
    trivial = LinearAction(SO3(), rho=lambda g: jnp.eye(3, dtype=g.dtype))
    system = vj.System(SO3(), lagrangian, jnp.asarray(3.0), advected=(LinearAction(SO3()), np.eye(3)[2]), additional=trivial)
    return system, vj.State(jnp.eye(3), jnp.array([0.3, -0.2, 0.5]), jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, 0.0, -0.2]))


def _attitude_mass_system():
    """A mass (2 + a_z)M that follows the advected a = Rᵀe_z: P = (2 + a_z)Mν − …, affine in ν
    alone, with coefficients that read the state."""
    J, M = np.diag([2.0, 3.0, 4.0]), np.diag([5.0, 6.0, 7.0])
    lagrangian = lambda xi, n, nu, a, p: 0.5 * xi @ J @ xi + 0.5 * (2 + a[2]) * nu @ M @ nu - p * n @ a  # noqa: E731
    system = vj.System(SO3(), lagrangian, jnp.asarray(9.81), advected=(LinearAction(SO3()), np.eye(3)[2]), additional=LinearAction(SO3()))
    return system, vj.State(jnp.eye(3), jnp.array([0.3, -0.2, 0.5]), jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, 0.0, -0.2]))


SCENES = {"cross term": _cross_term_system, "spring": _spring_system, "attitude mass": _attitude_mass_system}


def _scene(name):
    if name in SCENES:
        return SCENES[name]()
    system = vj.models.UnderwaterVehicle() if name == "vehicle" else vj.models.HeavyTop()
    return system, system.initial_state()


@pytest.fixture
def newton_on_every_unknown(monkeypatch, fresh_programs):
    """A switch to Newton on every unknown. The switch is read at trace time and programs are
    cached by their arguments, which it does not change: compiled programs are dropped on the
    switch (the next call traces anew) and after the test (no other test reuses one)."""

    def switch():
        monkeypatch.setattr(_advance, "explicit_unknowns", lambda *args: None)
        fresh_programs()

    return switch


def _found(system, x0, order):
    rule, _ = composition_coefficients(order)
    return explicit_unknowns(system, difference_map("cayley"), rule, _initial(system, x0), jnp.asarray(0.01))


@pytest.mark.parametrize(
    "name, order, expected",
    [
        ("vehicle", 1, ([3, 4, 5], [3, 4, 5])),  # eq. 74: ν explicit, (mI + M_A)ν = …
        ("vehicle", 2, None),  # the trapezoid's P rows hold ρ(Λ)ᵀℓ_ν: ν and ξ together
        ("heavy top", 1, None),  # no additional dynamics: ξ alone, Newton on all of it
        ("cross term", 1, None),
        ("spring", 4, ([3, 4, 5], [3, 4, 5])),
        ("attitude mass", 1, ([3, 4, 5], [3, 4, 5])),
    ],
)
def test_explicit_unknowns_found_from_the_jacobian(name, order, expected):
    assert _found(*_scene(name), order) == expected


@pytest.mark.parametrize(
    "name, order, concrete",
    [("spring", 1, True), ("spring", 4, True), ("spring", 4, False), ("attitude mass", 1, True), ("attitude mass", 1, False)],
)
def test_explicit_first_on_any_scene_equals_newton_on_every_unknown(newton_on_every_unknown, name, order, concrete):
    """Explicit unknowns solved first and Newton on every unknown: the same trajectory to Newton's
    tolerance (as below), on scenes beyond the vehicle — coefficients that differ between
    sub-step fractions (order 4: traced fractions in a concrete call, a scan over static ones
    under ``jit``), coefficients that read the state."""
    system, x0 = _scene(name)
    n_steps = 200
    call = lambda x: vj.simulate(system, x, 0.05, n_steps, order=order)  # noqa: E731
    run = call if concrete else jax.jit(call)
    explicit = run(x0)
    newton_on_every_unknown()
    every = run(x0)
    bound = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "q", "M", "P", "xi", "nu"):
        ours, theirs = np.asarray(getattr(explicit, field)), np.asarray(getattr(every, field))
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field


def test_explicit_first_equals_newton_on_every_unknown(newton_on_every_unknown):
    """The vehicle at h = 0.05 (large steps: Newton's three iterations matter) with ν solved first
    and with Newton on all six unknowns: the same trajectory to Newton's tolerance 64ε per step
    (a random walk of √n such steps, a factor 4 for its tail), Kelvin–Noether to round-off in
    both, and the relative F⁻ residual within the tolerance at every step."""
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    n_steps = 400
    run = lambda: jax.jit(lambda x: vj.simulate(model, x, 0.05, n_steps, throw=False))(x0)  # noqa: E731
    explicit = run()
    newton_on_every_unknown()
    every = run()
    assert bool(explicit.succeeded) and bool(every.succeeded)
    bound = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "q", "M", "P", "xi", "nu"):
        ours, theirs = np.asarray(getattr(explicit, field)), np.asarray(getattr(every, field))
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field
    assert np.max(np.asarray(explicit.newton_residual)) <= 64 * EPS
    kn = np.asarray(explicit.kelvin_noether)
    assert np.max(np.abs(kn - kn[0])) <= 1e-11 * np.max(np.asarray(explicit.kelvin_noether_scale))
