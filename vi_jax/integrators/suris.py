"""Suris (2001), "Integrable discretizations of some cases of the rigid body dynamics".

Explicit, Poisson, integrable maps on e(n)* = (so(n) ⋉ R^n)* for any n ≥ 3:

* the discrete Lagrange top in the rest frame, map (31), with H_ε (32) and Lax pair (37)-(38);
* the discrete Lagrange top in the body frame, maps (42)-(43), with H̄_ε and Theorem 6.4;
* the discrete Clebsch case (c_jk = 1, a = b), map (50), with the Lax pair of Theorem 7.1.

Errata of spec 004 are built in: the corrected Lagrangian (49) has 2/ε (the paper prints
4/ε); Theorem 6.4 uses U(λ) = [[0, λA], [+λAᵀ, 0]]; the Lax pairs (37) and Theorem 7.1 are
given for general |a| and |P| (the paper assumes |a| = 1, |P| = 1); the body-frame map
needs |A| = 1, which is checked. M, m are skew n×n matrices, P, A, a, p, b are n-vectors,
B = diag(b). Inputs are validated eagerly when concrete; everything is jittable,
vmappable and differentiable. Trajectories have a leading time axis of n_steps + 1 rows.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import _suris_algebra as _algebra
from ._suris_algebra import (
    cayley,
    cayley_apply,
    from_coordinates,
    pairing,
    skew_part,
    validated,
    wedge,
)

casimirs = validated(_algebra.casimirs)
orthogonal_block = validated(_algebra.orthogonal_block)
to_coordinates = validated(_algebra.to_coordinates)
lie_poisson_tensor = validated(_algebra.lie_poisson_tensor)

__all__ = [
    "pairing", "wedge", "cayley", "casimirs", "orthogonal_block", "lie_poisson_tensor",
    "to_coordinates", "from_coordinates",
    "lagrange_top_rest_frame_step", "lagrange_top_rest_frame",
    "lagrange_top_rest_frame_processed", "lagrange_top_rest_frame_hamiltonian",
    "lagrange_top_rest_frame_continuous_hamiltonian", "lagrange_top_rest_frame_vector_field",
    "lagrange_top_rest_frame_lax", "lagrange_top_rest_frame_lax_factor",
    "lagrange_top_rest_frame_increment", "lagrange_top_rest_frame_reconstruct",
    "lagrange_top_rest_frame_lagrangian",
    "lagrange_top_body_frame_step", "lagrange_top_body_frame",
    "lagrange_top_body_frame_processed", "lagrange_top_body_frame_hamiltonian",
    "lagrange_top_body_frame_continuous_hamiltonian", "lagrange_top_body_frame_vector_field",
    "lagrange_top_body_frame_lax", "lagrange_top_body_frame_lax_factor",
    "lagrange_top_body_frame_increment", "lagrange_top_body_frame_legendre",
    "lagrange_top_body_frame_reconstruct", "lagrange_top_body_frame_lagrangian",
    "clebsch_case_step", "clebsch_case", "clebsch_case_processed", "clebsch_integrals",
    "clebsch_continuous_hamiltonian", "clebsch_vector_field", "clebsch_lax",
    "clebsch_lax_factor", "clebsch_reconstruct", "clebsch_lagrangian",
]


# ------------------------------------------------------------------------ shared --

def _scan(step, x0, n_steps):
    def body(x, _):
        y = step(*x)
        return y, y

    _, ys = jax.lax.scan(body, x0, None, length=n_steps)
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), x0, ys)


def _accumulate(increments, left):
    """g_0 = I and g_{k+1} = w_k g_k (left) or g_k W_k (right)."""
    g0 = jnp.eye(increments.shape[-1], dtype=increments.dtype)

    def body(g, w):
        g1 = w @ g if left else g @ w
        return g1, g1

    _, gs = jax.lax.scan(body, g0, increments)
    return jnp.concatenate([g0[None], gs])


def _bordered(X, u):
    """The (n+1)×(n+1) matrix [[X, u], [uᵀ, 0]]."""
    n = X.shape[-1]
    return jnp.zeros((n + 1, n + 1), X.dtype).at[:n, :n].set(X).at[:n, n].set(u).at[n, :n].set(u)


def _log_det_one_plus(W):
    """log det(I + W) = tr log(2I + W + W⁻¹)/2 for W ∈ SO(n) (spec §0)."""
    return jnp.linalg.slogdet(jnp.eye(W.shape[-1], dtype=W.dtype) + W)[1]


# ---------------------------------------------------- Lagrange top, rest frame (6.1) --

def _rest_step(m, a, p, eps):
    m1 = m + eps * wedge(a, p)
    return m1, cayley_apply(0.5 * eps * m1, a)


def _rest_traj(m0, a0, p, eps, n_steps):
    return _scan(lambda m, a: _rest_step(m, a, p, eps), (m0, a0), n_steps)


def _rest_increment(m_next, a, a_next, alpha, eps):
    kick = (1 - alpha) * wedge(a, a_next) / (1 + a @ a_next)
    return cayley((0.5 * eps * m_next + kick) / alpha)


@validated
def lagrange_top_rest_frame_step(m, a, p, eps):
    """Map (31): m' = m + ε a∧p, a' = cay(ε m'/2) a. Independent of α; Poisson for (25)-(26)."""
    return _rest_step(m, a, p, eps)


@validated
def lagrange_top_rest_frame(m0, a0, p, eps, n_steps):
    """n_steps of map (31) from (m0, a0); returns (m, a) with n_steps + 1 rows."""
    return _rest_traj(m0, a0, p, eps, n_steps)


@validated
def lagrange_top_rest_frame_processed(m0, a0, p, eps, n_steps):
    """Second-order output of (31) by half kicks (spec §6.7): map (31) is run from
    m0 - (ε/2) a0∧p and m_k + (ε/2) a_k∧p is returned (conjugate to a Strang splitting)."""
    m, a = _rest_traj(m0 - 0.5 * eps * wedge(a0, p), a0, p, eps, n_steps)
    return m + 0.5 * eps * wedge(a, p), a


@validated
def lagrange_top_rest_frame_hamiltonian(m, a, p, eps):
    """H_ε (32) = <m,m>/2 + <a,p> - (ε/2)<m, p∧a>; exact integral of (31) for any |a|."""
    return 0.5 * pairing(m, m) + a @ p - 0.5 * eps * pairing(m, wedge(p, a))


@validated
def lagrange_top_rest_frame_continuous_hamiltonian(m, a, p):
    """H = <m,m>/2 + <a,p> of the rest-frame flow (24) (α-dependent part is a Casimir)."""
    return 0.5 * pairing(m, m) + a @ p


@validated
def lagrange_top_rest_frame_vector_field(m, a, p):
    """Flow (24) discretised by (31): (ṁ, ȧ) = (a∧p, m a)."""
    return wedge(a, p), m @ a


@validated
def lagrange_top_rest_frame_lax(m, a, p, eps, lam):
    """ℓ(λ) of Theorem 6.2 with b = (I - εm/2) a + (ε²/4)|a|² p (eq. (38), valid for any |a|).

    ℓ_{k+1}(λ) = v_k⁻¹ ℓ_k(λ) v_k with v_k from :func:`lagrange_top_rest_frame_lax_factor`."""
    b = a - 0.5 * eps * (m @ a) + 0.25 * eps**2 * (a @ a) * p
    return _bordered(m, lam * b - p / lam)


@validated
def lagrange_top_rest_frame_lax_factor(a, eps, lam):
    """v(λ) = cay((ε/2) u(λ)), u = [[0, λa], [λaᵀ, 0]] (Theorem 6.2); needs ελ|a| ≠ ±2."""
    return cayley(0.5 * eps * _bordered(jnp.zeros((a.shape[0],) * 2, a.dtype), lam * a))


@validated
def lagrange_top_rest_frame_increment(m_next, a, a_next, alpha, eps):
    """w_k = g_{k+1} g_k⁻¹ from the Legendre relation (36), solved as w_k = cay(X_k) with
    X_k = (ε/2α)[m_{k+1} + (2(1-α)/ε) a_k∧a_{k+1}/(1 + <a_k, a_{k+1}>)]."""
    return _rest_increment(m_next, a, a_next, alpha, eps)


@validated
def lagrange_top_rest_frame_reconstruct(m_traj, a_traj, alpha, eps):
    """g_k ∈ SO(n) along a trajectory (m_k, a_k) of (31): g_0 = I, g_{k+1} = w_k g_k with
    w_k from (36). Then a_k = g_k a_0, and (27) with A = a_0 is stationary along g_k."""
    w = jax.vmap(_rest_increment, (0, 0, 0, None, None))(
        m_traj[1:], a_traj[:-1], a_traj[1:], alpha, eps)
    return _accumulate(w, left=True)


@validated
def lagrange_top_rest_frame_lagrangian(g, g_next, A, p, alpha, eps):
    """Discrete Lagrangian (27), w = g_{k+1} g_k⁻¹, a_k = g_k A:
    -(α/ε) tr log(2I + w + w⁻¹) - (2(1-α)/ε) log(1 + <a_k, a_{k+1}>) - ε<p, a_k>."""
    a, a_next = g @ A, g_next @ A
    return (-(2 * alpha / eps) * _log_det_one_plus(g_next @ g.T)
            - (2 * (1 - alpha) / eps) * jnp.log1p(a @ a_next) - eps * (p @ a))


# ---------------------------------------------------- Lagrange top, body frame (6.2) --

def _body_increment(M, A, alpha, eps):
    c = cayley_apply(0.5 * eps * M, A)                         # (44): W A = c
    return cayley((0.5 * eps * M + (1 - alpha) * wedge(A, c) / (1 + A @ c)) / alpha)


def _body_step(M, P, A, alpha, eps):
    W = _body_increment(M, A, alpha, eps)
    P1 = W.T @ P
    return skew_part(W.T @ M @ W) + eps * wedge(A, P1), P1


def _body_traj(M0, P0, A, alpha, eps, n_steps):
    return _scan(lambda M, P: _body_step(M, P, A, alpha, eps), (M0, P0), n_steps)


def _omega(M, A, alpha):
    return (M + (1 - alpha) * wedge(A, M @ A)) / alpha


@validated
def lagrange_top_body_frame_step(M, P, A, alpha, eps):
    """Maps (42)-(43) in closed form: W = cay(X), X = [(ε/2)M + (1-α) A∧c/(1 + <A,c>)]/α,
    c = cay(εM/2) A (eq. (44)); P' = Wᵀ P, M' = Wᵀ M W + ε A∧P'. Needs |A| = 1."""
    return _body_step(M, P, A, alpha, eps)


@validated
def lagrange_top_body_frame(M0, P0, A, alpha, eps, n_steps):
    """n_steps of maps (42)-(43) from (M0, P0); returns (M, P) with n_steps + 1 rows."""
    return _body_traj(M0, P0, A, alpha, eps, n_steps)


@validated
def lagrange_top_body_frame_processed(M0, P0, A, alpha, eps, n_steps):
    """Second-order output of (42) by half kicks (spec §6.7): (42) is run from
    M0 + (ε/2) A∧P0 and M_k - (ε/2) A∧P_k is returned."""
    M, P = _body_traj(M0 + 0.5 * eps * wedge(A, P0), P0, A, alpha, eps, n_steps)
    return M - 0.5 * eps * wedge(A, P), P


@validated
def lagrange_top_body_frame_increment(M, A, alpha, eps):
    """W_k = g_k⁻¹ g_{k+1} solving the Legendre relation (43) for given M_k (closed form)."""
    return _body_increment(M, A, alpha, eps)


@validated
def lagrange_top_body_frame_legendre(W, A, alpha, eps):
    """Eq. (43): M = (2α/ε)(W - I)(W + I)⁻¹ - (2(1-α)/ε) A∧(WA)/(1 + <A, WA>)."""
    eye = jnp.eye(A.shape[0], dtype=W.dtype)
    X = jnp.linalg.solve((W + eye).T, (W - eye).T).T
    WA = W @ A
    return (2 * alpha / eps) * X - (2 * (1 - alpha) / eps) * wedge(A, WA) / (1 + A @ WA)


@validated
def lagrange_top_body_frame_reconstruct(M_traj, A, alpha, eps):
    """g_k along a trajectory M_k of (42): g_0 = I, g_{k+1} = g_k W_k; then P_k = g_kᵀ P_0."""
    W = jax.vmap(_body_increment, (0, None, None, None))(M_traj[:-1], A, alpha, eps)
    return _accumulate(W, left=False)


@validated
def lagrange_top_body_frame_hamiltonian(M, P, A, eps):
    """H̄_ε = <M,M>/2 + <P,A> + (ε/2)<M, P∧A>; exact integral of (42) (Theorem 6.3)."""
    return 0.5 * pairing(M, M) + P @ A + 0.5 * eps * pairing(M, wedge(P, A))


@validated
def lagrange_top_body_frame_continuous_hamiltonian(M, P, A, alpha):
    """H = <M,M>/(2α) - (1-α)|MA|²/(2α) + <P,A> = <M,Ω>/2 + <P,A> (Section 5)."""
    return 0.5 * pairing(M, _omega(M, A, alpha)) + P @ A


@validated
def lagrange_top_body_frame_vector_field(M, P, A, alpha):
    """Flow (15) discretised by (42): Ṁ = [M,Ω] + A∧P, Ṗ = -ΩP, Ω = [M + (1-α)A∧(MA)]/α."""
    Om = _omega(M, A, alpha)
    return M @ Om - Om @ M + wedge(A, P), -Om @ P


@validated
def lagrange_top_body_frame_lax(M, P, A, eps, lam):
    """L(λ) of Theorem 6.4 with B = (I + εM/2) A + (ε²/4) P (|A| = 1).

    L_{k+1}(λ) = V_k⁻¹ L_k(λ) V_k with V_k from :func:`lagrange_top_body_frame_lax_factor`."""
    return _bordered(M, lam * (A + 0.5 * eps * (M @ A) + 0.25 * eps**2 * P) - P / lam)


@validated
def lagrange_top_body_frame_lax_factor(M, A, alpha, eps, lam):
    """V(λ) = diag(W, 1) cay((ε/2) U(λ)), U = [[0, λA], [+λAᵀ, 0]] (Theorem 6.4 with the
    sign corrected, spec §3c); W from (43). Needs ελ ≠ ±2."""
    n = M.shape[0]
    W = jnp.eye(n + 1, dtype=M.dtype).at[:n, :n].set(_body_increment(M, A, alpha, eps))
    return W @ cayley(0.5 * eps * _bordered(jnp.zeros_like(M), lam * A))


@validated
def lagrange_top_body_frame_lagrangian(g, g_next, A, p, alpha, eps):
    """Discrete Lagrangian (39), W = g_k⁻¹ g_{k+1}, P_k = g_k⁻¹ p:
    -(α/ε) tr log(2I + W + W⁻¹) - (2(1-α)/ε) log(1 + <A, WA>) - ε<P_k, WA>."""
    W = g.T @ g_next
    WA = W @ A
    return (-(2 * alpha / eps) * _log_det_one_plus(W)
            - (2 * (1 - alpha) / eps) * jnp.log1p(A @ WA) - eps * ((g.T @ p) @ WA))


# ---------------------------------------------------------------- Clebsch case (7) --
# b must satisfy 1 + ε²|P|² b_i/4 > 0 for all i (checked): the denominators of (50) stay
# positive on the whole orbit and D of Theorem 7.1 is finite.

def _clebsch_step(M, P, b, eps):
    BP = b * P
    M1 = M + eps * wedge(P, BP) / (1 + 0.25 * eps**2 * (P @ BP))
    return M1, cayley_apply(-0.5 * eps * M1, P)


def _clebsch_traj(M0, P0, b, eps, n_steps):
    return _scan(lambda M, P: _clebsch_step(M, P, b, eps), (M0, P0), n_steps)


def _clebsch_q_d(M, P, b, eps):
    return P + 0.5 * eps * (M @ P), 1.0 / (1 + 0.25 * eps**2 * (P @ P) * b)


@validated
def clebsch_case_step(M, P, b, eps):
    """Map (50): M' = M + ε P∧(BP)/(1 + (ε²/4)<P,BP>), P' = cay(-εM'/2) P."""
    return _clebsch_step(M, P, b, eps)


@validated
def clebsch_case(M0, P0, b, eps, n_steps):
    """n_steps of map (50) from (M0, P0); returns (M, P) with n_steps + 1 rows."""
    return _clebsch_traj(M0, P0, b, eps, n_steps)


@validated
def clebsch_case_processed(M0, P0, b, eps, n_steps):
    """Second-order output of (50) by half kicks (spec §6.7): (50) is run from
    M0 - (ε/2) P0∧BP0 and M_k + (ε/2) P_k∧BP_k is returned."""
    M, P = _clebsch_traj(M0 - 0.5 * eps * wedge(P0, b * P0), P0, b, eps, n_steps)
    return M + 0.5 * eps * wedge(P, b * P), P


@validated
def clebsch_integrals(M, P, b, eps):
    """(I_1, E_ε) of map (50) from tr L(λ)² (Theorem 7.1, general |P|, spec §4):
    I_1 = qᵀDq, E_ε = -[tr(DMDM) + 2 qᵀDBDq]/4, q = (I + εM/2)P, D = (I + ε²|P|²B/4)⁻¹."""
    q, d = _clebsch_q_d(M, P, b, eps)
    DM = d[:, None] * M
    return q @ (d * q), -0.25 * (jnp.trace(DM @ DM) + 2 * q @ (d * b * d * q))


@validated
def clebsch_continuous_hamiltonian(M, P, b):
    """H = <M,M>/2 - <P,BP>/2 of the flow (48)."""
    return 0.5 * pairing(M, M) - 0.5 * P @ (b * P)


@validated
def clebsch_vector_field(M, P, b):
    """Flow (48) discretised by (50): Ṁ = P∧(BP), Ṗ = -MP."""
    return wedge(P, b * P), -M @ P


@validated
def clebsch_lax(M, P, b, eps, lam):
    """L(λ) = D(λB + M + λ⁻¹ q qᵀ) of Theorem 7.1 with D = (I + ε²|P|²B/4)⁻¹ (general |P|).

    L_{k+1}(λ) = V_k L_k(λ) V_k⁻¹ with V_k from :func:`clebsch_lax_factor`."""
    q, d = _clebsch_q_d(M, P, b, eps)
    return d[:, None] * (lam * jnp.diag(b) + M + jnp.outer(q, q) / lam)


@validated
def clebsch_lax_factor(P, b, eps, lam):
    """V(λ) = cay((ε/2λ) 𝒬), 𝒬 = P Pᵀ(I + ε²|P|²B/4)/(1 + (ε²/4)<P,BP>) (Theorem 7.1,
    general |P|). 𝒬 has rank one with eigenvalue |P|², so ε|P|² ≠ 2λ is needed."""
    Q = jnp.outer(P, P * (1 + 0.25 * eps**2 * (P @ P) * b)) / (1 + 0.25 * eps**2 * P @ (b * P))
    return cayley(0.5 * eps / lam * Q)


@validated
def clebsch_reconstruct(M_traj, eps):
    """g_k along a trajectory M_k of (50): g_0 = I, g_{k+1} = g_k cay(εM_{k+1}/2)."""
    return _accumulate(jax.vmap(cayley)(0.5 * eps * M_traj[1:]), left=False)


@validated
def clebsch_lagrangian(g, g_next, p, b, eps):
    """Discrete Lagrangian (49) as corrected in spec §4 (2/ε, not the printed 4/ε):
    -(1/ε) tr log(2I + W + W⁻¹) + (2/ε) log(1 + (ε²/4)<P_k, BP_k>), P_k = g_k⁻¹ p."""
    P = g.T @ p
    return (-(2 / eps) * _log_det_one_plus(g.T @ g_next)
            + (2 / eps) * jnp.log1p(0.25 * eps**2 * P @ (b * P)))
