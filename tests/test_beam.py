"""Seed 003: the multisymplectic Lie-group integrator and the geometrically exact beam.

Every check compares the engine with an independent computation: autodiff of the discrete
action, closed forms, an RK4 reference, a hand-written leapfrog, d'Alembert's solution, or an
exact conservation/balance law. Grids are small; each march shape is compiled once.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax.multisymplectic as ms
from vi_jax import lie
from vi_jax.models._beam import GeometricallyExactBeam

SE3 = lie.SE3()
RNG = np.random.default_rng(3)
EPS = np.finfo(np.float64).eps


@pytest.fixture(autouse=True)
def _reseed():
    """The same random data for a test whether it runs alone or in the suite."""
    global RNG
    RNG = np.random.default_rng(3)


def dcel_round_off(model, g, dt, ds):
    """Bound on the DCEL residual (68) of a beam field g that solves it. The residual recomputes
    ξ = cay⁻¹(g⁻¹g')/Δt and η = cay⁻¹(g⁻¹g'')/Δs from configurations rounded to ε·max|g|, so each
    of its four momentum terms (𝕁ξ/Δt, 𝕂η/Δs) carries ≲ 4ε·max|g|·(𝕁/Δt² + 𝕂/Δs²); 16× covers
    their sum (measured ≤ 1.4×). Newton's own tolerance (64ε·|μ|/Δt) lies far below this."""
    stiffness = float(jnp.max(model.inertia / dt**2 + model.stiffness / ds**2))
    return 16 * EPS * float(jnp.max(jnp.abs(g))) * stiffness


def rel_err(a, b, scale=None):
    a, b = np.asarray(a), np.asarray(b)
    return np.max(np.abs(a - b)) / (np.max(np.abs(b)) if scale is None else scale)


def unit_beam():
    """A beam with O(1) inertia and stiffness, so that every component of a residual counts."""
    return GeometricallyExactBeam(length=1.0, side=1.0, youngs_modulus=10.0, poisson_ratio=0.3, mass_density=1.0)


def random_field(group, rows, cols, scale):
    """g_a^j = cay(x_a^j) with random x: a rough field, so that every term of the DCEL matters."""
    x = scale * RNG.standard_normal((rows, cols, group.dim))
    return jax.jit(jax.vmap(jax.vmap(group.cay)))(jnp.asarray(x))


def spd(n, scale):
    a = RNG.standard_normal((n, n))
    return jnp.asarray(scale * (a @ a.T / n + np.eye(n)))


def quartic_system(group):
    """ℓ = ½ξᵀJξ − ½ηᵀKη − ¼(η·η)² with random SPD J, K: a separable, non-quadratic density."""
    J, K = spd(group.dim, 1.0), spd(group.dim, 2.0)
    return ms.CovariantSystem(group, lambda xi, eta: 0.5 * xi @ J @ xi - 0.5 * eta @ K @ eta - 0.25 * (eta @ eta) ** 2)


# --- SE(3) Cayley primitives and the variation formula (66) against autodiff -----------------


@jax.jit
def _se3_errors(x, y, zeta1, zeta2, h):
    X, eye4 = SE3.hat(x), jnp.eye(4)
    w, v = x[:3], x[3:]
    g = SE3.cay(x)
    cay_matrix = jnp.linalg.solve(eye4 - X / 2, eye4 + X / 2)
    R = jnp.eye(3) + 4 / (4 + w @ w) * (lie.SO3().hat(w) + lie.SO3().hat(w) @ lie.SO3().hat(w) / 2)
    t = (4 * jnp.eye(3) + 2 * lie.SO3().hat(w) + jnp.outer(w, w)) @ v / (4 + w @ w)
    T = SE3.right_trivialised_tangent(SE3.cay, x)
    dcay_form = SE3.vee((eye4 - X / 2) @ SE3.hat(y) @ (eye4 + X / 2))
    k = SE3.cay(y)
    Ad_direct = jax.vmap(lambda e: SE3.vee(k @ SE3.hat(e) @ SE3.inverse(k)), out_axes=1)(jnp.eye(6))
    Rk, rk = k[:3, :3], k[:3, 3]
    dual_formula = jnp.concatenate([Rk @ zeta1[:3] + jnp.cross(rk, Rk @ zeta1[3:]), Rk @ zeta1[3:]])
    # (66): δξ = dτ⁻¹_{hξ}(−ζ₁ + Ad_{τ(hξ)}ζ₂)/h for g₁ → g₁cay(εζ₁), g₂ → g₂cay(εζ₂), g₂ = g₁τ(hξ)
    g1, g2 = SE3.cay(y), SE3.cay(y) @ SE3.cay(h * x)
    xi_of = lambda e: SE3.cay_inv(SE3.inverse(g1 @ SE3.cay(e * zeta1)) @ g2 @ SE3.cay(e * zeta2)) / h  # noqa: E731
    d_xi = jax.jvp(xi_of, (0.0,), (1.0,))[1]
    d_xi_66 = SE3.dcay_inv(h * x) @ (-zeta1 + SE3.Ad(SE3.cay(h * x)) @ zeta2) / h
    return {
        "cay in SE(3)": SE3.membership_error(g),
        "cay = (I − X/2)⁻¹(I + X/2)": jnp.max(jnp.abs(g - cay_matrix)),
        "closed-form R and translation (spec §2)": jnp.max(jnp.abs(g[:3, :3] - R)) + jnp.max(jnp.abs(g[:3, 3] - t)),
        "cay⁻¹∘cay = id": jnp.max(jnp.abs(SE3.cay_inv(g) - x)) / jnp.max(jnp.abs(x)),
        "dcay⁻¹ = (autodiff T)⁻¹": jnp.max(jnp.abs(SE3.dcay_inv(x) @ T - jnp.eye(6))),
        "dcay⁻¹_X(Y) = (I − X/2)Y(I + X/2)": jnp.max(jnp.abs(SE3.dcay_inv(x) @ y - dcay_form)) / jnp.max(jnp.abs(dcay_form)),
        "Ad_g = [[R, 0], [r̂R, R]]": jnp.max(jnp.abs(SE3.Ad(k) - Ad_direct)),
        "Ad*_{g⁻¹} = (Rπ + r×Rp, Rp)": jnp.max(jnp.abs(SE3.Ad(SE3.inverse(k)).T @ zeta1 - dual_formula)),
        "variation formula (66)": jnp.max(jnp.abs(d_xi - d_xi_66)) / jnp.max(jnp.abs(d_xi)),
    }


def test_se3_cayley_primitives_against_autodiff():
    for _ in range(20):
        x, y, z1, z2 = (jnp.asarray(RNG.uniform(-1.5, 1.5, 6)) for _ in range(4))
        for name, err in _se3_errors(x, y, z1, z2, 0.3).items():
            assert float(err) <= 1e-12, (name, float(err))


# --- DCEL two-way check and local Noether -----------------------------------------------------

DT, DS = 0.1, 0.2


@eqx.filter_jit
def _dcel_check(system, g, f_nodes, tau="cayley"):
    G = system.group

    def action(eps):
        gp = g @ jax.vmap(jax.vmap(G.cay))(eps)
        forcing = DS * DT * jnp.sum(f_nodes[:-1, :-1] * eps[:-1, :-1])  # F̄¹ = ΔsΔt f (eq. 39)
        return ms.discrete_action(system, gp, dt=DT, ds=DS, tau=tau) + forcing

    grad = jax.grad(action)(jnp.zeros(g.shape[:2] + (G.dim,), g.dtype))
    force = lambda t, s, gj: f_nodes[jnp.rint(t / DT).astype(int), jnp.rint(s / DS).astype(int)]  # noqa: E731
    residual = ms.dcel_residual(system, g, dt=DT, ds=DS, tau=tau, force=force)
    P = ms.vertex_momenta(system, g, dt=DT, ds=DS, tau=tau)
    J1, J2, J3 = ms.triangle_momentum_maps(system, g, dt=DT, ds=DS, tau=tau)

    def vertex_map(k, j, a, zeta):
        """⟨J^k, ζ⟩ = d/dε L_d with vertex k moved to cay(εζ)g⁽ᵏ⁾ (eq. 35)."""
        verts = [g[j, a], g[j + 1, a], g[j, a + 1]]
        verts[k] = G.cay(zeta) @ verts[k]
        one_triangle = jnp.stack([jnp.stack([verts[0], verts[2]]), jnp.stack([verts[1], verts[1]])])
        return ms.discrete_action(system, one_triangle, dt=DT, ds=DS, tau=tau)

    J_auto = [jax.grad(functools.partial(vertex_map, k, 1, 2))(jnp.zeros(G.dim, g.dtype)) for k in range(3)]
    return grad, residual, P, (J1, J2, J3), J_auto


SYSTEMS = {  # (system, difference map τ)
    "SE3-beam-cayley": (unit_beam, "cayley"),
    "SO3-exp": (lambda: quartic_system(lie.SO3()), "exp"),
    "SO4": (lambda: quartic_system(lie.SOn(4)), "cayley"),
    "R2": (lambda: quartic_system(lie.Rn(2)), "cayley"),
}


@pytest.mark.parametrize("name", SYSTEMS)
def test_dcel_residual_equals_gradient_of_discrete_action_and_local_noether(name):
    make, tau = SYSTEMS[name]
    system = make()
    G = system.group
    g = random_field(G, 5, 6, 0.4)
    f_nodes = jnp.asarray(RNG.standard_normal((5, 6, G.dim)))
    grad, residual, P, J, J_auto = _dcel_check(system, g, f_nodes, tau)
    scale = max(float(jnp.max(jnp.abs(p))) for p in P) / (DS * DT)
    # (68)–(71) from explicit μ, λ vs the left-trivialised gradient of S_d (plus eq. 39's forces)
    assert rel_err(residual, -grad / (DS * DT), scale) <= 1e-11
    # local Noether (36): J¹ + J² + J³ = 0 on every triangle, each J^k at its own vertex
    total = J[0] + J[1] + J[2]
    size = jnp.abs(J[0]) + jnp.abs(J[1]) + jnp.abs(J[2])
    assert float(jnp.max(jnp.max(jnp.abs(total), -1) / jnp.max(size, -1))) <= 1e-14
    # the explicit J^k (eq. 77) equal the autodiff momentum maps of eq. (35)
    for k in range(3):
        assert rel_err(J[k][1, 2], J_auto[k]) <= 1e-11


# --- the beam's time march: conservation, energy, symplecticity, Noether on rectangles ----------
# One compiled program serves most checks: the first variation (jvp) of a 4,000-step free–free march
# of the default beam on a small grid; its primal output is the march itself.

N_NODES, N_STEPS = 6, 4000
ZERO_TANGENT = (jnp.zeros((N_NODES, 6)), jnp.zeros((N_NODES, 6)))


@functools.cache
def beam_setup():
    model = GeometricallyExactBeam()
    ds = float(model.length) / N_NODES
    dt = 0.5 * float(model.stable_time_step(ds))
    g0, xi0 = model.initial_state(N_NODES)
    return model, ds, dt, g0, xi0


def beam_jvp(V=ZERO_TANGENT, model=None, d_system=None):
    base, ds, dt, g0, xi0 = beam_setup()
    return ms.time_march_jvp(base if model is None else model, g0, xi0, V, d_system=d_system, dt=dt, ds=ds, n_steps=N_STEPS)


@functools.cache
def free_beam_run():
    return beam_jvp()[0]


def test_free_free_momentum_conserved_and_energy_without_drift():
    sol = free_beam_run()
    assert bool(sol.succeeded)
    J = np.asarray(sol.momentum)
    assert J.shape == (N_STEPS + 1, 6) and np.all(np.abs(J[0]) > 1e-7)  # all six components non-trivial
    assert np.max(np.abs(J - J[0])) <= 1e-12 * np.linalg.norm(J[0])
    E = np.asarray(sol.energy)
    rel = E / E[0] - 1
    band = np.ptp(rel)
    assert band < 1e-2  # bounded
    # no drift: the slope of 10 block means is within 3 standard errors of zero and its change
    # over the run is a small fraction of the oscillation band
    blocks = rel[:N_STEPS].reshape(10, -1).mean(axis=1)
    x = np.arange(10.0)
    slope, intercept = np.polyfit(x, blocks, 1)
    se = np.sqrt(np.sum((blocks - slope * x - intercept) ** 2) / 8 / np.sum((x - x.mean()) ** 2))
    assert abs(slope) <= 3 * se
    assert abs(slope) * 10 <= 0.05 * band


@eqx.filter_jit
def _field_checks(model, g, dt, ds):
    """One compilation for the field diagnostics of a march."""
    return (
        ms.dcel_residual(model, g, dt=dt, ds=ds),
        ms.vertex_momenta(model, g, dt=dt, ds=ds),
        ms.triangle_momentum_maps(model, g, dt=dt, ds=ds),
        ms.time_momentum_map(model, g, dt=dt, ds=ds),
    )


def test_free_free_march_solves_the_dcel_and_covariant_noether_on_rectangles():
    model, ds, dt, _, _ = beam_setup()
    sol = free_beam_run()
    g = sol.g[:40]  # rows 0..39 of the field, free end included
    res, _, J, J_time = _field_checks(model, g, dt, ds)
    # (82) at inner rows and every column; (83): the free ends, node 0 and the slaved node A
    assert float(jnp.max(jnp.abs(res[1:-1]))) <= dcel_round_off(model, g, dt, ds)
    for _ in range(5):
        K, L = sorted(RNG.choice(38, 2, replace=False))
        B, C = sorted(RNG.choice(N_NODES, 2, replace=False))
        total, size = ms.covariant_momentum(*J, (K, L), (B, C))
        assert float(jnp.max(jnp.abs(total))) <= 1e-11 * float(jnp.max(size))  # Theorem 3.3
    # 𝖩⁺_𝖫 from the field's J² equals the march's momentum; the field recomputes ξ = cay⁻¹(g⁻¹g')/Δt
    # from the configurations, which costs eps/(Δt|ξ|) ≈ 2e-12 of relative precision
    assert rel_err(J_time, sol.momentum[:39]) <= 1e-10


def test_time_map_symplectic_and_multisymplectic_formula():
    model, ds, dt, g0, xi0 = beam_setup()
    V, W = [(jnp.asarray(RNG.standard_normal((N_NODES, 6))), jnp.asarray(RNG.standard_normal((N_NODES, 6)))) for _ in range(2)]
    omega, scale = ms.time_map_symplecticity(model, g0, xi0, V, W, dt=dt, ds=ds, n_steps=N_STEPS)
    omega, scale = np.asarray(omega), np.asarray(scale)
    assert abs(omega[0]) > 1e-3 * scale[0]  # a non-degenerate pair of variations
    assert np.max(np.abs(omega - omega[0])) <= 1e-10 * np.max(scale)
    zetas = []
    for tangent in (V, W):  # the same compiled first variation as inside time_map_symplecticity
        sol, d_sol = beam_jvp(tangent)
        zetas.append(ms.field_variation(SE3, sol.g, d_sol.g))
    g = sol.g
    for rows, cols in [((0, N_STEPS - 1), (0, N_NODES - 1)), ((3, 3000), (1, 4)), ((100, 250), (0, 2))]:
        value, size = ms.multisymplectic_formula(model, g, *zetas, rows, cols, dt=dt, ds=ds)
        assert abs(float(value)) <= 1e-10 * float(size)


def test_parameter_sensitivity_by_implicit_forward_mode():
    """d(tip position)/dE through the implicit solves equals central finite differences."""
    model = beam_setup()[0]
    E = float(model.youngs_modulus)
    with_E = lambda e: eqx.tree_at(lambda m: m.youngs_modulus, model, jnp.asarray(e))  # noqa: E731
    d_E = eqx.tree_at(lambda m: m.youngs_modulus, jax.tree.map(jnp.zeros_like, eqx.filter(model, eqx.is_inexact_array)), jnp.asarray(1.0))
    tangent = beam_jvp(d_system=d_E)[1].g[-1, -1, :3, 3]
    tip = lambda e: beam_jvp(model=with_E(e))[0].g[-1, -1, :3, 3]  # noqa: E731
    fd = (tip(E * (1 + 1e-6)) - tip(E * (1 - 1e-6))) / (2e-6 * E)  # O(h²) error ≈ 3e-7 (measured)
    assert float(jnp.max(jnp.abs(fd))) * E > 1e-4  # the stiffness matters at the tip
    assert rel_err(tangent, fd) <= 1e-5


def test_vmap_in_float32_matches_the_float64_run():
    """A batch of two float32 marches: member 0 matches the float64 march to float32 precision,
    and both conserve momentum to float32 precision."""
    model, ds, dt, g0, xi0 = beam_setup()
    ref = free_beam_run()
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    batch = f32(jnp.stack([xi0, 1.1 * xi0]))
    sols = jax.vmap(lambda x: ms.time_march(model, f32(g0), xi0=x, dt=f32(dt), ds=f32(ds), n_steps=60))(batch)
    assert sols.g.dtype == jnp.float32 and sols.g.shape == (2, 61) + ref.g.shape[1:] and bool(sols.succeeded)
    # a few ε₃₂ per step adding like a random walk: 30√60·ε₃₂ = 2.8e-5 (a 6ε₃₂ step at 5σ); measured
    # 1.2e-6 on CPU; TF32 products (unit round-off 2⁻¹¹) gave 2.8e-4 on an H100
    assert rel_err(sols.g[0], ref.g[:61]) <= 30 * np.sqrt(60) * np.finfo(np.float32).eps
    J = np.asarray(sols.momentum, np.float64)
    assert np.max(np.abs(J - J[:, :1])) <= 1e-5 * np.max(np.abs(J))
