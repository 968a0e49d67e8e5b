"""Explicit splitting (vi_jax/discrete/_splitting*.py), the method itself: the pieces' flows
generate the continuous EP vector field; every composition has its order (on linear flows, where
the order conditions are those of the free Lie algebra); the default orders converge at slopes
2/4/6/8 to an independent hand-written reference (vehicle and heavy top).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

import vi_jax as vj
from vi_jax import continuous
from vi_jax.discrete import _splitting as S
from vi_jax.discrete import _splitting_pieces as sp
from vi_jax.discrete._splitting_pieces import from_phase, piece_flows, separable_parts, to_phase
from vi_jax.lie import SO3, SOn

VEHICLE = vj.models.UnderwaterVehicle()
TOP = vj.models.HeavyTop()
FULL_INERTIA = np.array([[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 1.0]])


def hat(x):
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


# --- the pieces generate the continuous vector field -------------------------------------------
GENERATOR_SCENES = {
    "vehicle": lambda: VEHICLE,
    "heavy top, full inertia, CoM off axis": lambda: vj.models.HeavyTop(inertia=FULL_INERTIA, center_of_mass=(0.1, -0.2, 0.5)),
    "heavy top on SO(4)": lambda: vj.models.HeavyTop(group=SOn(4)),
}


@pytest.mark.parametrize(
    "name, sphere", [(name, False) for name in GENERATOR_SCENES] + [(name, True) for name in GENERATOR_SCENES if "SO(4)" not in name]
)
def test_pieces_generate_the_continuous_vector_field(name, sphere):
    """Σ_pieces d/dt|₀ flow(t, x) = the continuous EP field (vi_jax.continuous) in momentum form:
    ġ, q̇ and Π̇ = Jξ̇, Ṗ = Mν̇ (J, M the Hessians of ℓ), at a random state, with planar rotations
    about the three principal axes or the sphere piece and two planar rotations. Signs and factors
    of every piece are checked here; the composition then has the order of its coefficients."""
    system = GENERATOR_SCENES[name]()
    G = system.group
    rng = np.random.default_rng(1)
    g, xi = G.exp(jnp.asarray(rng.normal(size=G.dim))), jnp.asarray(rng.normal(size=G.dim))
    q = qdot = None
    if system.has_additional:
        q, qdot = jnp.asarray(rng.normal(size=3)), jnp.asarray(rng.normal(size=3))
    x = vj.State(g, xi, q, qdot)

    @jax.jit  # one compilation instead of op-by-op dispatch
    def both_sides(parts, system, x):
        state = S.splitting_initial_state(system, x)
        phase = to_phase(parts, state.g, state.q, state.M, state.P)
        rates = [jax.jvp(lambda t, f=f: from_phase(parts, f(t, phase)), (0.0,), (1.0,))[1] for f in piece_flows(parts).values()]
        total = functools.reduce(lambda a, b: jax.tree.map(jnp.add, a, b), rates)
        y = continuous.initial_state(system, x)
        g_dot, xi_dot, q_dot, nu_dot = continuous.time_derivative(system, y)
        n, a = system.body_configuration(x.g, x.q), system.body_advected(x.g)
        expected = [g_dot, q_dot, jax.hessian(system.lagrangian)(x.xi, n, y[3], a) @ xi_dot, None]
        if system.has_additional:
            expected[3] = jax.hessian(system.lagrangian, argnums=2)(x.xi, n, y[3], a) @ nu_dot
        return total, expected

    total, expected = both_sides(separable_parts(system, sphere=sphere), system, x)
    for got, want in zip(total, expected):
        if want is None:
            assert got is None
            continue
        scale = float(jnp.max(jnp.abs(want))) + 1.0
        # Both sides are a few dozen products of O(1) numbers (plus the field's 6×6 solve).
        assert float(jnp.max(jnp.abs(got - want))) <= 1e-12 * scale, (got, want)


# --- the rotations: small-angle polynomials and the SO(3) form -----------------------------------
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_rotation_increments(dtype):
    """cos θ − 1 and sin θ of both plans: the loop option's Taylor polynomials for |θ| ≤ 1
    (remainders below 1/20! ≈ 4e-19 for values, 1/19! ≈ 8e-18 for derivatives) and the default
    plan's half-angle trig, against float64 references, values and derivatives. cos θ − 1 must
    hold to a few ulp *of itself* (relative), not of 1: a rotation by the same angle at every step
    would otherwise rescale g by the same rounding every time and drift off SO(3)."""
    theta = np.concatenate([np.linspace(-1.0, 1.0, 2001), [1e-4, -3e-6]]).astype(dtype)
    exact = theta.astype(np.float64)
    cm1_exact = -2 * np.sin(exact / 2) ** 2
    eps = np.finfo(dtype).eps
    for fn in (sp._cos_minus_one_sin_small, sp._cos_minus_one_sin_trig):
        (cm1, s), (dcm1, ds) = jax.jit(lambda t, fn=fn: jax.jvp(fn, (t,), (jnp.ones_like(t),)))(jnp.asarray(theta))
        assert cm1.dtype == s.dtype == dtype
        for got, want in ((cm1, cm1_exact), (s, np.sin(exact)), (dcm1, -np.sin(exact)), (ds, np.cos(exact))):
            assert np.all(np.abs(np.asarray(got, np.float64) - want) <= 4 * eps * np.abs(want) + 1e-300), fn.__name__


def _random_phase(parts, seed):
    rng = np.random.default_rng(seed)
    G = parts.system.group
    P = jnp.asarray(rng.normal(size=3)) if parts.system.has_additional else None
    q = jnp.asarray(rng.normal(size=3)) if parts.system.has_additional else None
    return sp.Phase(G.exp(jnp.asarray(rng.normal(size=G.dim))), q, jnp.asarray(rng.normal(size=G.dim)), P)


@pytest.mark.parametrize("system", [VEHICLE, TOP], ids=["vehicle", "heavy top"])
def test_rotation_plans_agree(system, monkeypatch):
    """``rotate`` under the loop-option plan (the polynomials behind a ``lax.cond``) equals the
    default plan (``jnp.cos``/``jnp.sin``) on both sides of the branch |θ| = 1, values and
    t-derivatives; and on SO(3) its one product on the rows of (g', Π', P') equals the per-array
    form with Ad* from the algebra's coordinate pairs (the SO(n) form). Each side is a few
    products of O(1) numbers: agreement to 64ε."""
    parts = separable_parts(system)
    phase = _random_phase(parts, 3)

    def flows(parts, plan):
        monkeypatch.setattr(sp, "loop_option_requested", lambda: plan)

        @jax.jit
        def run(parts, phase):
            out = []
            for k in range(3):
                theta_per_t = phase.Pi[k] * parts.inv_inertia[k]
                for angle in (0.3, 2.5):  # |θ| below and above 1
                    t = angle / theta_per_t
                    out.append(jax.jvp(lambda t, k=k: sp.rotate(parts, k, t, phase), (t,), (jnp.ones_like(t),)))
            return out

        return run(parts, phase)

    reference = flows(parts, False)
    per_array = eqx.tree_at(lambda p: p.frame, parts, replace=None)
    for got in (flows(parts, True), flows(per_array, False)):
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(reference)):
            assert float(jnp.max(jnp.abs(a - b))) <= 64 * np.finfo(np.float64).eps * (1 + float(jnp.max(jnp.abs(b))))


@pytest.mark.parametrize("system", [VEHICLE, TOP], ids=["vehicle", "heavy top"])
def test_sphere_plans_agree(system, monkeypatch):
    """The sphere piece under both plans (the polynomials of u = θ² behind a ``lax.cond``; the
    default plan's ``where``) equals g'·exp(φ̂) by ``SO3().exp``, φ = tΠ'/I₁, and E^TP', with Π'
    unchanged, on both sides of the branch θ = 1, values and t-derivatives (64ε: a few
    products of O(1) numbers); at Π' = 0 values and derivatives are finite (the double-where)."""
    parts = separable_parts(system, sphere=True)
    phase = _random_phase(parts, 5)

    def flows(plan):
        monkeypatch.setattr(sp, "loop_option_requested", lambda: plan)

        @jax.jit
        def run(parts, phase):
            theta_per_t = jnp.linalg.norm(phase.Pi) * parts.inv_inertia[1]
            return [jax.jvp(lambda t: sp.sphere(parts, t, phase), (a / theta_per_t,), (1.0 / theta_per_t,)) for a in (0.4, 2.5)]

        return run(parts, phase)

    @jax.jit
    def by_exp(parts, phase):
        def flow(t):
            E = SO3().exp(t * parts.inv_inertia[1] * phase.Pi)
            return sp.Phase(phase.g @ E, phase.q, phase.Pi, None if phase.P is None else E.T @ phase.P)

        theta_per_t = jnp.linalg.norm(phase.Pi) * parts.inv_inertia[1]
        return [jax.jvp(flow, (a / theta_per_t,), (1.0 / theta_per_t,)) for a in (0.4, 2.5)]

    reference = by_exp(parts, phase)
    for got in (flows(True), flows(False)):
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(reference)):
            assert float(jnp.max(jnp.abs(a - b))) <= 64 * np.finfo(np.float64).eps * (1 + float(jnp.max(jnp.abs(b))))
    at_rest = phase._replace(Pi=jnp.zeros(3))
    for plan in (True, False):
        monkeypatch.setattr(sp, "loop_option_requested", lambda: plan)
        grad = jax.grad(lambda Pi: jnp.sum(sp.sphere(parts, 0.7, at_rest._replace(Pi=Pi)).g ** 2))(at_rest.Pi)
        assert np.all(np.isfinite(grad))


def test_principal_frame():
    """J = U diag(I) Uᵀ with U ∈ SO(3); a diagonal J keeps the body frame (U = I exactly)."""
    parts = separable_parts(vj.models.HeavyTop(inertia=FULL_INERTIA))
    U, moments = np.asarray(parts.frame), 1 / np.asarray(parts.inv_inertia)
    np.testing.assert_allclose(U.T @ U, np.eye(3), atol=1e-15)
    assert abs(np.linalg.det(U) - 1) <= 1e-15
    np.testing.assert_allclose(U @ np.diag(moments) @ U.T, FULL_INERTIA, atol=1e-14)
    for system in (VEHICLE, TOP):  # TOP: degenerate moments (1, 1, 0.4)
        parts = separable_parts(system)
        assert np.array_equal(np.asarray(parts.frame), np.eye(3))
        np.testing.assert_allclose(1 / np.asarray(parts.inv_inertia), np.diagonal(system.inertia), rtol=1e-15)
    np.testing.assert_allclose(
        np.asarray(separable_parts(VEHICLE).inv_mass), np.linalg.inv(VEHICLE.mass * np.eye(3) + VEHICLE.added_mass), rtol=1e-14
    )
    # For the sphere piece the axes are relabelled cyclically: the middle moment on axis 1.
    for inertia in (FULL_INERTIA, np.diag([5.0, 3.0, 4.0]), np.diag([1.0, 2.0, 3.0]), np.diag([2.0, 2.0, 1.0])):
        parts = separable_parts(vj.models.HeavyTop(inertia=inertia), sphere=True)
        U, moments = np.asarray(parts.frame), 1 / np.asarray(parts.inv_inertia)
        assert moments[1] == np.sort(moments)[1]
        assert abs(np.linalg.det(U) - 1) <= 1e-15
        np.testing.assert_allclose(U @ np.diag(moments) @ U.T, inertia, atol=1e-14)


# --- every composition has its order ------------------------------------------------------------
_RNG = np.random.default_rng(0)
_MATS = [_RNG.normal(size=(5, 5)) / 2 for _ in range(3)]
_Y0 = _RNG.normal(size=5).astype(complex)
_EIG = [(w, V, np.linalg.inv(V)) for w, V in map(np.linalg.eig, _MATS)]  # exp(tA) = V e^{tw} V⁻¹


def _flow(k, t, y, xp=np):
    w, V, Vi = _EIG[k]
    return V @ (xp.exp(t * w) * (Vi @ y))


def _composition(method, h, n_steps=2):
    """Φ*_{α_s h}∘Φ_{β_s h}∘…∘Φ_{β₁h}, n_steps times, as written in the module's docstring, on
    ẏ = (A₀ + A₁ + A₂)y with the exact flows exp(tA_k) (Φ_t applies A₀, A₁, A₂; Φ*_t the reverse)."""
    y = _Y0
    for _ in range(n_steps):
        for i, c in enumerate(S.METHODS[method][1]):
            for k in (0, 1, 2) if i % 2 == 0 else (2, 1, 0):
                y = _flow(k, c * h, y)
    return y


@pytest.mark.parametrize("method", list(S.METHODS))
def test_every_method_has_its_order(method):
    """Local error ~ h^(p+1) on random 5×5 matrices (generic matrices represent the free Lie
    algebra, so their order conditions are those of any splitting)."""
    order = S.METHODS[method][0]
    # h|A| in the range where the error is dominated by its leading h^(p+1) term, above round-off.
    hs = {2: (0.05, 0.025, 0.0125), 4: (0.05, 0.025, 0.0125), 6: (0.2, 0.1, 0.05), 8: (0.4, 0.2, 0.1)}[order]
    errors = [float(np.max(np.abs(_composition(method, h) - scipy.linalg.expm(2 * h * sum(_MATS)) @ _Y0))) for h in hs]
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert min(errors) >= 1e-13, errors  # far above round-off (~1e-15)
    # The next error term still adds up to +0.5 to the fitted slope at the larger h (measured
    # 3.1–3.2, 5.1–5.2, 7.2–7.5, 9.4–9.6); a method of lower order could not exceed p + 0.75.
    assert order + 0.75 <= slope <= order + 1.6, (errors, slope)


def test_stage_loop_is_the_composition():
    """The module's rolled stage loop (adjacent flows merged, the last flow of a step merged with
    the first of the next) = the plain composition, for a method with α_i ≠ β_i."""
    method = "blanes_moan10"
    flows = {k: functools.partial(_flow, k, xp=jnp) for k in range(3)}
    table = S.stage_table(method)
    h = jnp.asarray(0.1)
    y = S._steps(flows, (0, 1, 2), table, h, S._first(flows, (0, 1, 2), table[0, 0], h, _Y0), 2)
    assert float(np.max(np.abs(np.asarray(y) - _composition(method, 0.1)))) <= 1e-13


# --- convergence against an independent hand-written reference ---------------------------------
def vehicle_field(m):
    """Hand-written EP equations of the vehicle (seed 000 eq. 62): with Π = Jω, P = Mν, a = Rᵀe_z,
    Π̇ = Π×ω + P×ν − B r×a,  Ṗ = P×ω + (W − B)a,  Ṙ = Rω̂,  q̇ = Rν."""
    Ji = np.linalg.inv(np.asarray(m.inertia))
    Mi = np.linalg.inv(float(m.mass) * np.eye(3) + np.asarray(m.added_mass))
    W, B, r = float(m.mass * m.gravity), float(m.buoyancy), np.asarray(m.buoyancy_offset)

    def f(t, y):
        R, Pi, P = y[:9].reshape(3, 3), y[12:15], y[15:]
        w, nu, a = Ji @ Pi, Mi @ P, R[2]
        Pi_dot = np.cross(Pi, w) + np.cross(P, nu) - B * np.cross(r, a)
        return np.concatenate([(R @ hat(w)).ravel(), R @ nu, Pi_dot, np.cross(P, w) + (W - B) * a])

    return f


def top_field(m):
    """Hand-written heavy top: Π̇ = Π×ω + mg Γ×χ (Γ = Rᵀe_z, gravity along −e_z), Ṙ = Rω̂."""
    Ji, mgchi = np.linalg.inv(np.asarray(m.inertia)), float(m.mass * m.gravity) * np.asarray(m.center_of_mass)

    def f(t, y):
        R, Pi = y[:9].reshape(3, 3), y[9:]
        w = Ji @ Pi
        return np.concatenate([(R @ hat(w)).ravel(), np.cross(Pi, w) + np.cross(R[2], mgchi)])

    return f


def hand_reference(system, T):
    """(R(T), q(T)) by scipy's DOP853 at rtol = atol = 1e-13 on the hand-written field (agrees
    with vi_jax.continuous.solve/Dopri8 at 1e-14 to ~1e-13)."""
    x0 = system.initial_state()
    R0 = np.asarray(x0.g)
    Pi0 = np.asarray(system.inertia) @ np.asarray(x0.xi)
    if system.has_additional:
        M = float(system.mass) * np.eye(3) + np.asarray(system.added_mass)
        y0, f = np.concatenate([R0.ravel(), np.asarray(x0.q), Pi0, M @ R0.T @ np.asarray(x0.qdot)]), vehicle_field(system)
    else:
        y0, f = np.concatenate([R0.ravel(), Pi0]), top_field(system)
    y = solve_ivp(f, (0.0, T), y0, method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
    return y[:9].reshape(3, 3), (y[9:12] if system.has_additional else None)


@functools.cache
def _runner(pieces):
    """n steps of a (zero-padded) stage table, n and the table traced, so that the orders share
    one compilation per order of the pieces. The module's own first flow, stage loop and flows."""

    @jax.jit
    def run(parts, x0, h, n, table, beta1):
        system = parts.system
        flows = piece_flows(parts)
        state = S.splitting_initial_state(system, x0)
        s = S._first(flows, pieces, beta1, h, to_phase(parts, state.g, state.q, state.M, state.P))
        return from_phase(parts, S._steps(flows, pieces, table, h, s, n))

    return run


def run_steps(system, x0, h, n, order, arrangement=None):
    """n steps of the default method of ``order`` (in its default arrangement, or ``arrangement``)."""
    method, arrangement = S.resolve(order, arrangement=arrangement)
    table = S.stage_table(method)
    longest = max(len(S.stage_table(S.resolve(o)[0])) for o in S.ORDERS)
    padded = np.vstack([np.zeros((longest - len(table), 3)), table])
    sphere = "S" in arrangement
    names = (("V", "T") if system.has_additional else ("V",)) + (("S", 0, 2) if sphere else (0, 1, 2))
    pieces = S.arrange(names, arrangement)
    parts = separable_parts(system, sphere=sphere)
    return _runner(pieces)(parts, x0, jnp.asarray(h), n, jnp.asarray(padded), jnp.asarray(table[0, 0]))


CONVERGENCE = {
    # scene, T, step counts per order (errors between ~1e-2 and ~1e-10, above the reference's
    # 1e-13) for the planar rotations and, where they differ, for the sphere piece (1,000× smaller
    # errors on the symmetric top: its free motion is then exact)
    "vehicle": (VEHICLE, 20.0, {2: (80, 160, 320), 4: (20, 40, 80), 6: (20, 40, 80), 8: (30, 60, 120)}, {}),
    "heavy top": (
        TOP, 1.0, {2: (50, 100, 200), 4: (25, 50, 100), 6: (15, 30, 60), 8: (8, 16, 32)},
        {4: (10, 20, 40), 6: (4, 8, 16), 8: (2, 4, 8)},
    ),
}


@functools.cache
def _reference(name):
    system, T, _, _ = CONVERGENCE[name]
    return hand_reference(system, T)


@pytest.mark.parametrize("sphere", [True, False], ids=["sphere piece", "planar rotations"])
@pytest.mark.parametrize("order", S.ORDERS)
@pytest.mark.parametrize("name", list(CONVERGENCE))
def test_convergence_order(name, order, sphere):
    """Fitted slope of the final-state error of the default method of each order, in its default
    arrangement of the pieces (the sphere piece) and in the same without it."""
    system, T, planar_counts, sphere_counts = CONVERGENCE[name]
    counts = sphere_counts.get(order, planar_counts[order]) if sphere else planar_counts[order]
    arrangement = S.resolve(order, sphere=sphere)[1]
    R_ref, q_ref = _reference(name)
    errors = []
    for n in counts:
        g, q, _, _ = run_steps(system, system.initial_state(), T / n, n, order, arrangement)
        err = float(np.max(np.abs(np.asarray(g) - R_ref)))
        if q_ref is not None:
            err = max(err, float(np.max(np.abs(np.asarray(q) - q_ref))))
        errors.append(err)
    slope = np.polyfit(np.log(np.asarray(counts, float)), np.log(errors), 1)[0]
    assert abs(-slope - order) <= 0.2, (errors, slope)
