"""Seed 003, scenarios: forces and the clamped end, the rigid-body limit, the linear wave
equation, the space march and the paper's scenario, input validation (the engine's identities
and the free–free march are in tests/test_beam.py).

Every check compares the engine with an independent computation: autodiff of the discrete
action, closed forms, an RK4 reference, a hand-written leapfrog, d'Alembert's solution, or an
exact conservation/balance law. Grids are small; each march shape is compiled once.
"""

import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax.multisymplectic as ms
from vi_jax import lie
from vi_jax.models._beam import GeometricallyExactBeam

from test_beam import N_NODES, N_STEPS, beam_setup, dcel_round_off, rel_err

SE3 = lie.SE3()
E6 = jnp.eye(6)[5]
RNG = np.random.default_rng(3)
EPS = np.finfo(np.float64).eps


@pytest.fixture(autouse=True)
def _reseed():
    """The same random data for a test whether it runs alone or in the suite."""
    global RNG
    RNG = np.random.default_rng(3)

# --- forces and the clamped end ---------------------------------------------------------------


def test_uniform_force_changes_linear_momentum_by_its_impulse():
    """With a spatially uniform force density F (body wrench (0, Rᵀ F)), the total linear momentum
    grows exactly linearly: P(t_j) = P(0) + t_j·(Σ_a Δs)·F (forced Noether, Thm 3.4)."""
    model, ds, dt, g0, xi0 = beam_setup()
    F = float(model.mass_density * model.area) * jnp.asarray([0.3, -0.2, -9.81])  # a tilted gravity
    force = lambda t, s, g: jnp.concatenate([jnp.zeros(3), g[:3, :3].T @ F])  # noqa: E731
    sol = ms.time_march(model, g0, xi0=xi0, dt=dt, ds=ds, n_steps=600, force=force)
    P = np.asarray(sol.momentum[:, 3:])
    expected = P[0] + np.asarray(sol.t)[:, None] * N_NODES * ds * np.asarray(F)
    assert np.max(np.abs(expected - P[0])) > 1e-3 * np.max(np.abs(P[0]))  # the force matters
    assert rel_err(P, expected) <= 1e-12
    res = ms.dcel_residual(model, sol.g, dt=dt, ds=ds, force=force)
    assert float(jnp.max(jnp.abs(res[1:-1]))) <= dcel_round_off(model, sol.g, dt, ds)


def test_clamped_free_keeps_the_clamp_conserves_energy_and_solves_the_dcel():
    model, ds, dt, g0, xi0 = beam_setup()
    sol = ms.time_march(model, g0, xi0=xi0.at[0].set(0.0), dt=dt, ds=ds, n_steps=N_STEPS, boundary="clamped-free")
    assert bool(sol.succeeded)
    assert float(jnp.max(jnp.abs(sol.g[:, 0] - g0[0]))) == 0.0
    rel = np.asarray(sol.energy) / float(sol.energy[0]) - 1
    # bounded: the band (O(Δt) for the spec's E_L, K taken at ξ^j) does not grow
    assert np.ptp(rel) <= 2e-2 and np.ptp(rel[N_STEPS // 2 :]) <= 1.1 * np.ptp(rel[: N_STEPS // 2])
    res = ms.dcel_residual(model, sol.g[:60], dt=dt, ds=ds)
    # (82)–(83) away from the clamp; at the clamp, its reaction
    assert float(jnp.max(jnp.abs(res[1:-1, 1:]))) <= dcel_round_off(model, sol.g[:60], dt, ds)
    assert float(jnp.max(jnp.abs(res[1:-1, 0]))) > 1e-6 * float(jnp.max(jnp.abs(sol.mu))) / dt


# --- rigid-body limit: order 2 with the consistent start -----------------------------------------

RB_J = jnp.asarray([1.0, 2.0, 3.0, 0.5, 0.5, 0.5])
RB_XI = jnp.asarray([0.3, -0.85, 0.5, 0.1, -0.1, 0.2])


@functools.partial(jax.jit, static_argnums=1)
def _rk4_rigid_body(T, n):
    """Reference: classical RK4 on ġ = gξ̂, μ̇ = ad*_ξ μ, μ = Jξ (continuous Euler–Poincaré)."""

    def f(y):
        g, mu = y
        xi = mu / RB_J
        return g @ SE3.hat(xi), SE3.ad(xi).T @ mu

    def step(y, _):
        h = T / n
        k1 = f(y)
        k2 = f(jax.tree.map(lambda a, b: a + h / 2 * b, y, k1))
        k3 = f(jax.tree.map(lambda a, b: a + h / 2 * b, y, k2))
        k4 = f(jax.tree.map(lambda a, b: a + h * b, y, k3))
        return jax.tree.map(lambda a, b1, b2, b3, b4: a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4), y, k1, k2, k3, k4), None

    return jax.lax.scan(step, (jnp.eye(4), RB_J * RB_XI), None, length=n)[0][0]


def test_rigid_body_limit_converges_at_order_two():
    system = ms.CovariantSystem(SE3, lambda xi, eta: 0.5 * xi @ (RB_J * xi) - 0.5 * (eta - E6) @ (eta - E6))
    g_ref = _rk4_rigid_body(2.0, 20_000)
    hs = np.array([0.04, 0.02, 0.01, 0.005])
    errors = []
    for h in hs:  # one compiled march of 400 steps; g(T) is row T/h
        sol = ms.time_march(system, jnp.eye(4)[None], xi0=RB_XI[None], dt=h, ds=1.0, n_steps=400)
        errors.append(float(jnp.max(jnp.abs(sol.g[int(round(2.0 / h)), 0] - g_ref))))
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert 1.95 <= slope <= 2.05, (errors, slope)
    # spec §5 test 5, printed to 3 digits (rounding ≤ 4.5e-3 relative, at 1.12e-4)
    np.testing.assert_allclose(errors, [1.79e-3, 4.48e-4, 1.12e-4, 2.80e-5], rtol=5e-3)


# --- the linear wave equation: leapfrog, exact at Courant number 1 ------------------------------

R1 = lie.Rn(1)
WAVE = ms.CovariantSystem(R1, lambda xi, eta: 0.5 * xi @ xi - 0.5 * eta @ eta)  # c = 1


def bump(x, width):
    return np.clip(1 - (x / width) ** 2, 0, None) ** 4


def embed(u):
    return jax.vmap(lambda x: R1.cay(jnp.atleast_1d(x)))(jnp.asarray(u))


def test_wave_equation_time_march_is_leapfrog_and_exact_at_courant_one():
    h, A, n = 0.05, 41, 12
    s = h * np.arange(A)
    u = lambda t: bump(s - t - 0.6, 0.25) + 0.5 * bump(s + t - 1.3, 0.2)  # noqa: E731  (d'Alembert)
    sol = ms.time_march(WAVE, embed(u(0)), g1=embed(u(h)), dt=h, ds=h, n_steps=n)
    U = np.asarray(sol.g[:, :-1, 0, 1])
    rows = [u(0), u(h)]  # hand leapfrog with the same zero-traction ends (eq. 83)
    for _ in range(n - 1):
        x = rows[-1]
        lap = np.zeros(A)
        lap[:-1] += x[1:] - x[:-1]
        lap[1:] -= x[1:] - x[:-1]
        rows.append(2 * x - rows[-2] + lap)
    assert np.max(np.abs(U - np.array(rows))) <= 1e-12
    assert np.max(np.abs(U - np.array([u(j * h) for j in range(n + 1)]))) <= 1e-12


def test_reverse_mode_gradient_through_the_implicit_solves():
    """jax.grad of a quadratic loss of a (linear) wave march equals its central difference exactly."""
    h, A = 0.05, 21
    s = h * np.arange(A)
    g0 = embed(bump(s - 0.5, 0.2))
    xi0 = jnp.asarray(np.cos(3 * s)[:, None])
    loss = lambda x: jnp.sum(ms.time_march(WAVE, g0, xi0=x, dt=0.8 * h, ds=h, n_steps=10).g[-1, :, 0, 1] ** 2)  # noqa: E731
    grad = jax.grad(loss)(xi0)
    direction = jnp.asarray(RNG.standard_normal(xi0.shape))
    fd = (loss(xi0 + 1e-3 * direction) - loss(xi0 - 1e-3 * direction)) / 2e-3
    assert abs(float(fd)) > 1e-3
    np.testing.assert_allclose(jnp.sum(grad * direction), fd, rtol=1e-9)


def test_wave_equation_space_march_is_exact_at_courant_one():
    h, N, A = 0.05, 61, 21
    t, s = h * np.arange(N), h * np.arange(A)
    # waves that enter and leave [0, 1] within (0, T): zero near the rows j = 0 and N − 1
    u = lambda t, s: bump(s - t + 1.2, 0.25) + 0.5 * bump(s + t - 2.0, 0.25)  # noqa: E731
    sol = ms.space_march(WAVE, embed(u(t, 0.0)), embed(u(t, h)), dt=h, ds=h, n_columns=A)
    exact = u(t[:, None], s[None, :])
    assert np.max(np.abs(exact)) > 0.5
    assert np.max(np.abs(np.asarray(sol.g[:-1, :, 0, 1]) - exact)) <= 1e-12


# --- the space march: Noether, symplecticity, the paper's scenario -------------------------------


@functools.cache
def space_data():
    model = GeometricallyExactBeam()
    dt, ds, N = 0.04, 0.02, 21
    t = dt * np.arange(N)
    b = np.sin(np.pi * t / t[-1]) ** 3  # rest-to-rest driving of column 0
    col0 = jnp.stack([
        jnp.eye(4).at[:3, :3].set(lie.SO3().cay(jnp.asarray([0.0, 0.003 * bj, 0.0]))).at[0, 3].set(0.01 * bj) for bj in b
    ])
    col1 = col0 @ SE3.cay(ds * jnp.asarray([0.2, -0.1, 0.5, 0.001, 0.002, 1.001]))  # pre-strained
    return model, dt, ds, col0, col1


def test_space_march_conserves_its_momentum_map_and_is_symplectic():
    model, dt, ds, col0, col1 = space_data()
    N = col0.shape[0]
    V, W = [tuple(jnp.asarray(RNG.standard_normal((N, 6))) * 1e-2 for _ in range(2)) for _ in range(2)]
    sol, _ = ms.space_march_jvp(model, col0, col1, V, dt=dt, ds=ds, n_columns=6)  # compiled once, with ω below
    J = np.asarray(sol.momentum)
    scale = dt * np.sum(np.abs(np.asarray(sol.lam)), axis=(0, 2))
    assert np.max(np.abs(J - J[0]).max(axis=1) / scale) <= 1e-9 and np.max(np.abs(J[0])) > 1e-2
    # 𝖩 sums the march's own λ; space_momentum_map recomputes η = cay⁻¹(g⁻¹g'')/Δs from the field,
    # so each of its N terms Δt·Ad*λ is off by ≲ 4ε·max|g|²·𝕂/Δs
    floor = N * dt * 4 * EPS * float(jnp.max(jnp.abs(sol.g))) ** 2 * float(jnp.max(model.stiffness)) / ds
    np.testing.assert_allclose(ms.space_momentum_map(model, sol.g, dt=dt, ds=ds), J[:-1], rtol=0, atol=floor)
    omega, size = ms.space_map_symplecticity(model, col0, col1, V, W, dt=dt, ds=ds, n_columns=6)
    omega, size = np.asarray(omega), np.asarray(size)
    assert abs(omega[0]) > 1e-3 * size[0]
    assert np.max(np.abs(omega - omega[0])) <= 1e-10 * np.max(size)


def test_paper_scenario_reproduces_anchors_and_warns():
    model = GeometricallyExactBeam()
    with pytest.warns(UserWarning) as record:
        col0, col1 = model.paper_space_data()
    messages = " ".join(str(w.message) for w in record)
    assert "zero velocity" in messages and "shear" in messages and "not reproducible" in messages
    assert col0.shape == (51, 4, 4)
    with pytest.warns(UserWarning, match="Newton failed at column"):
        sol = ms.space_march(model, col0, col1, dt=0.04, ds=0.02, n_columns=41, throw=False)
    np.testing.assert_allclose(sol.eta[0, 0], E6, atol=1e-12)
    # anchors printed to 4 decimals (rounding ≤ 5e-5); η of column 0 comes from the data alone
    np.testing.assert_allclose(sol.eta[25, 0], [1.8524, 0.0323, -2.9688, -0.7367, 0.0449, 1.1886], atol=1e-4)
    np.testing.assert_allclose(sol.eta[50, 0], [0.8455, -0.0275, -6.3259, -1.4181, 0.1394, 1.9654], atol=1e-4)
    assert 2 <= sol.valid_columns < 41
    with pytest.raises(ms.MarchFailure, match="column"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ms.space_march(model, col0, col1, dt=0.04, ds=0.02, n_columns=41)


# --- input validation ----------------------------------------------------------------------------


def test_bad_input_raises_clear_value_errors():
    model = GeometricallyExactBeam()
    g0, xi0 = model.initial_state(3)
    cases = [
        (dict(xi0=xi0, dt=-1.0, ds=0.1, n_steps=3), "dt"),
        (dict(xi0=xi0, dt=1e-4, ds=0.1, n_steps=0), "n_steps"),
        (dict(dt=1e-4, ds=0.1, n_steps=3), "xi0, g1"),
        (dict(xi0=xi0[:2], dt=1e-4, ds=0.1, n_steps=3), "xi0"),
        (dict(xi0=xi0, dt=1e-4, ds=0.1, n_steps=3, boundary="periodic"), "boundary"),
        (dict(xi0=xi0, dt=1e-4, ds=0.1, n_steps=4, save_every=3), "save_every"),
        (dict(xi0=xi0, dt=1e-4, ds=0.1, n_steps=3, boundary="clamped-free"), "clamped node"),
    ]
    for kwargs, name in cases:
        with pytest.raises(ValueError, match=name):
            ms.time_march(model, g0, **kwargs)
    with pytest.raises(ValueError, match="g0"):
        ms.time_march(model, g0.at[1, 0, 0].set(2.0), xi0=xi0, dt=1e-4, ds=0.1, n_steps=3)
    with pytest.raises(ValueError, match="poisson_ratio"):
        GeometricallyExactBeam(poisson_ratio=0.7)
    with pytest.raises(ValueError, match="youngs_modulus"):
        GeometricallyExactBeam(youngs_modulus=0.0)
    coupled = ms.CovariantSystem(SE3, lambda xi, eta: 0.5 * xi @ xi - 0.5 * (eta - E6) @ (eta - E6) + xi @ eta)
    with pytest.raises(ValueError, match="separable"):
        ms.time_march(coupled, g0, xi0=xi0, dt=1e-4, ds=0.1, n_steps=3)
    with pytest.raises(ValueError, match="n_columns"):
        ms.space_march(model, g0, g0, dt=0.1, ds=0.1, n_columns=1)
