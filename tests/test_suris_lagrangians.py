"""Physics tests of vi_jax.models.suris (Suris 2001; spec 004), second part: Lagrangians and
Legendre maps, convergence orders, transforms and dtypes, bad input (the exact integrals, Lax
identity and Poisson property are in tests/test_suris.py).

Relative errors of integrals are taken against the size of the terms they are made of
(e.g. |tr N^{2j}| ≤ ‖N‖_F^{2j}), so that a near-cancelling value does not inflate them.
Each check runs inside one jitted function per test case: XLA compiles dominate the runtime.
"""

import jax

jax.config.update("jax_enable_x64", True)

from functools import partial  # noqa: E402

import diffrax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from vi_jax.models import suris  # noqa: E402

from test_suris import ALPHAS, check, make_data  # noqa: E402


# ------------------------------------------ Lagrangians, Legendre maps, frame change --

def el_residual(lagrangian, g):
    """max over interior nodes of |dS/dη| under g_j → cay(η) g_j, relative to one term."""
    n = g.shape[-1]
    x0 = jnp.zeros(n * (n - 1) // 2)

    def node(g_prev, g_j, g_next):
        def moved(x):
            eta = suris.from_coordinates(jnp.concatenate([x, jnp.zeros(n)]), n)[0]
            return suris.cayley(eta) @ g_j
        d1 = jax.grad(lambda x: lagrangian(g_prev, moved(x)))(x0)
        d2 = jax.grad(lambda x: lagrangian(moved(x), g_next))(x0)
        return jnp.max(jnp.abs(d1 + d2)) / jnp.max(jnp.abs(d1))

    return jnp.max(jax.vmap(node)(g[:-2], g[1:-1], g[2:]))


@jax.jit
def euler_lagrange_residuals(M0, A, p, b, eps):
    steps = 5
    good, checks = {}, {}
    for alpha in ALPHAS:
        m, a = suris.lagrange_top_rest_frame(M0, A, p, eps, steps)
        g = suris.lagrange_top_rest_frame_reconstruct(m, a, alpha, eps)
        checks[f"rest a_k = g_k A, {alpha}"] = jnp.max(jnp.abs(g @ A - a))
        good[f"rest (27), {alpha}"] = el_residual(
            lambda g0, g1: suris.lagrange_top_rest_frame_lagrangian(g0, g1, A, p, alpha, eps), g)
        M, P = suris.lagrange_top_body_frame(M0, p, A, alpha, eps, steps)
        g = suris.lagrange_top_body_frame_reconstruct(M, A, alpha, eps)
        checks[f"body P_k = g_kᵀ p, {alpha}"] = jnp.max(jnp.abs(jnp.swapaxes(g, 1, 2) @ p - P))
        good[f"body (39), {alpha}"] = el_residual(
            lambda g0, g1: suris.lagrange_top_body_frame_lagrangian(g0, g1, A, p, alpha, eps), g)
    M, P = suris.clebsch_case(M0, p, b, eps, steps)
    g = suris.clebsch_reconstruct(M, eps)
    checks["clebsch P_k = g_kᵀ p"] = jnp.max(jnp.abs(jnp.swapaxes(g, 1, 2) @ p - P))

    def clebsch(g0, g1):
        return suris.clebsch_lagrangian(g0, g1, p, b, eps)

    def clebsch_printed(g0, g1):                            # the paper's 4/ε in (49)
        P0 = g0.T @ p
        return clebsch(g0, g1) + (2 / eps) * jnp.log1p(0.25 * eps**2 * P0 @ (b * P0))

    good["clebsch (49), 2/eps"] = el_residual(clebsch, g)
    return good, checks, {"clebsch (49), printed 4/eps": el_residual(clebsch_printed, g)}


def test_discrete_euler_lagrange():
    """Maps (31), (42), (50) are stationary points of the actions of (27), (39), (49)."""
    d = make_data(4, 70)
    good, checks, bad = euler_lagrange_residuals(d.M, d.A, d.p, d.b, 0.3)
    check(good, 1e-13)
    check(checks, 1e-14)
    check(bad, 1e-3, above=True)


@jax.jit
def legendre_and_frame_residuals(M0, A, p, alpha, eps):
    n, steps = M0.shape[0], 20
    W = suris.lagrange_top_body_frame_increment(M0, A, alpha, eps)
    out = {"W orthogonal": jnp.max(jnp.abs(W.T @ W - jnp.eye(n))),
           "W A = cay(εM/2) A, (44)": jnp.max(jnp.abs(W @ A - suris.cayley(0.5 * eps * M0) @ A)),
           "(43) inverted": jnp.max(jnp.abs(
               suris.lagrange_top_body_frame_legendre(W, A, alpha, eps) - M0))}
    # (31) plus reconstruction is (42) seen from the body (spec §3c, frame change).
    m, a = suris.lagrange_top_rest_frame(M0, A, p, eps, steps)
    g = suris.lagrange_top_rest_frame_reconstruct(m, a, alpha, eps)
    gT = jnp.swapaxes(g, 1, 2)
    M_from_rest = gT @ (m + eps * suris.wedge(a, p)) @ g
    M, P = suris.lagrange_top_body_frame(M_from_rest[0], p, A, alpha, eps, steps)
    out["frame change M"] = jnp.max(jnp.abs(M - M_from_rest))
    out["frame change P"] = jnp.max(jnp.abs(P - gT @ p))
    return out


@pytest.mark.parametrize("alpha", ALPHAS)
def test_legendre_maps_and_frame_change(alpha):
    d = make_data(5, 80)
    check(legendre_and_frame_residuals(d.M, d.A, d.p, alpha, 0.25), 1e-13)


# ------------------------------------------------------------------ convergence --

T_END, ALPHA_ORDERS = 2.0, 0.4
NS_ORDERS = (100, 200, 400, 800)


@partial(jax.jit, static_argnums=0)
def final_states(N, M0, P0, A, p, b):
    """States at T_END of the six schemes, in the order of the reference below."""
    e = T_END / N
    runs = [suris.lagrange_top_rest_frame(M0, A, p, e, N),
            suris.lagrange_top_rest_frame_processed(M0, A, p, e, N),
            suris.lagrange_top_body_frame(M0, P0, A, ALPHA_ORDERS, e, N),
            suris.lagrange_top_body_frame_processed(M0, P0, A, ALPHA_ORDERS, e, N),
            suris.clebsch_case(M0, P0, b, e, N),
            suris.clebsch_case_processed(M0, P0, b, e, N)]
    return jax.tree.map(lambda y: y[-1], runs)


def test_orders():
    """Raw maps: order 1; half-kick processing: order 2 (against Dopri8, rtol=atol=1e-13)."""
    d = make_data(4, 90)
    M0, P0, A, p, b = map(jnp.asarray, (d.M, d.P, d.A, d.p, d.b))

    def field(t, y, args):
        (m, a), (Mb, Pb), (Mc, Pc) = y
        return (suris.lagrange_top_rest_frame_vector_field(m, a, p),
                suris.lagrange_top_body_frame_vector_field(Mb, Pb, A, ALPHA_ORDERS),
                suris.clebsch_vector_field(Mc, Pc, b))

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Dopri8(), 0.0, T_END, 0.01,
        ((M0, A), (M0, P0), (M0, P0)), max_steps=10_000,
        stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-13))
    ref = [y for y in jax.tree.map(lambda y: y[-1], sol.ys) for _ in range(2)]
    errors = np.array([[max(float(jnp.max(jnp.abs(u - v))) for u, v in zip(run, r))
                        for run, r in zip(final_states(N, M0, P0, A, p, b), ref)]
                       for N in NS_ORDERS])
    slopes = np.polyfit(np.log(T_END / np.array(NS_ORDERS)), np.log(errors), 1)[0]
    names = ["rest", "rest 2nd", "body", "body 2nd", "clebsch", "clebsch 2nd"]
    assert np.all(np.abs(slopes - [1, 2, 1, 2, 1, 2]) <= 0.1), dict(zip(names, slopes))


# ------------------------------------------------------- transforms and dtypes --

def test_vmap_grad_and_float32():
    d = make_data(4, 100)
    M0s = jnp.stack([d.M, 0.5 * d.M, -d.M])
    Ms, _ = jax.vmap(lambda M0: suris.lagrange_top_body_frame(M0, d.P, d.A, 0.4, 0.1, 50))(M0s)
    M1, _ = suris.lagrange_top_body_frame(0.5 * d.M, d.P, d.A, 0.4, 0.1, 50)
    assert Ms.shape == (3, 51, 4, 4)
    # vmap may round differently: two roundings of 50 steps part like a random walk, ≲ 30√50·ε·|M|
    # (a 6ε step at 5σ; measured 7.5e-15 = 2.4·√50·ε·|M|)
    eps, scale = np.finfo(np.float64).eps, float(jnp.max(jnp.abs(M1)))
    assert float(jnp.max(jnp.abs(Ms[1] - M1))) <= 30 * np.sqrt(50) * eps * scale

    def loss(eps):
        _, P = suris.clebsch_case(d.M, d.P, d.b, eps, 50)
        return jnp.sum(P[-1] ** 2 * d.b)

    g = jax.grad(loss)(0.1)
    fd = (loss(0.1 + 1e-6) - loss(0.1 - 1e-6)) / 2e-6
    assert abs(float(g - fd)) <= 1e-6 * max(1.0, abs(float(fd)))

    f32 = [jnp.asarray(x, jnp.float32) for x in (d.M, d.a, d.p)]
    m32, a32 = suris.lagrange_top_rest_frame(*f32, 0.1, 50)
    m64, _ = suris.lagrange_top_rest_frame(d.M, d.a, d.p, 0.1, 50)
    assert m32.dtype == jnp.float32 and a32.dtype == jnp.float32
    assert float(jnp.max(jnp.abs(m32 - m64))) <= 1e-4


# ------------------------------------------------------------------ bad input --

_D = make_data(3, 0)


@pytest.mark.parametrize("call, match", [
    (lambda: suris.lagrange_top_rest_frame(np.ones((3, 3)), _D.a, _D.p, 0.1, 5),
     r"m0: expected a skew-symmetric matrix .*got max\|M \+ Mᵀ\| = 2"),
    (lambda: suris.lagrange_top_rest_frame(np.zeros((2, 2)), _D.a[:2], _D.p[:2], 0.1, 5),
     r"m0: expected a skew-symmetric n×n matrix with n ≥ 3, got shape \(2, 2\)"),
    (lambda: suris.lagrange_top_rest_frame(_D.M, np.ones(4), _D.p, 0.1, 5),
     r"a0: expected a vector of shape \(3,\), got shape \(4,\)"),
    (lambda: suris.clebsch_case(_D.M, _D.P, _D.b, 0.0, 5),
     r"eps: expected a positive scalar, got 0.0"),
    (lambda: suris.clebsch_case(_D.M, _D.P, _D.b, np.inf, 5),
     r"eps: expected a finite scalar, got inf"),
    (lambda: suris.clebsch_case(_D.M, _D.P, _D.b, 0.1, 0),
     r"n_steps: expected an integer ≥ 1, got 0"),
    (lambda: suris.clebsch_case(_D.M, _D.P, _D.b, 0.1, 10.0),
     r"n_steps: expected an integer ≥ 1, got 10.0 \(float\)"),
    (lambda: suris.clebsch_case(_D.M, np.array([1.0, np.nan, 0.0]), _D.b, 0.1, 5),
     r"P0: expected finite values"),
    (lambda: suris.clebsch_case(_D.M, _D.P, -1e3 * np.ones(3), 0.5, 5),
     r"b: expected 1 \+ eps²\|P0\|² b_i/4 > 0 for every i"),
    (lambda: suris.lagrange_top_body_frame(_D.M, _D.P, 2 * _D.A, 0.4, 0.1, 5),
     r"A: expected a unit vector \(\|A\| = 1.*got \|A\| = 2"),
    (lambda: suris.lagrange_top_body_frame(_D.M, _D.P, _D.A, -1.0, 0.1, 5),
     r"alpha: expected a positive scalar, got -1.0"),
    (lambda: suris.clebsch_lax(_D.M, _D.P, _D.b, 0.1, 0.0),
     r"lam: expected a nonzero scalar, got 0.0"),
    (lambda: suris.clebsch_lagrangian(2 * np.eye(3), np.eye(3), _D.p, _D.b, 0.1),
     r"g: expected an orthogonal matrix \(gᵀg = I\), got max\|gᵀg - I\| = 3"),
    (lambda: suris.clebsch_reconstruct(np.zeros((1, 3, 3)), 0.1),
     r"M_traj: expected a trajectory of shape \(rows ≥ 2, n, n\) with n ≥ 3, got shape"),
    (lambda: suris.lagrange_top_rest_frame_reconstruct(np.zeros((4, 3, 3)), np.zeros((5, 3)),
                                                       1.0, 0.1),
     r"a_traj: expected shape \(4, 3\), got shape \(5, 3\)"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()
