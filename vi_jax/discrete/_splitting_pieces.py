"""Separable reduced Lagrangians ℓ(ξ, n, ν, a) = ½ξᵀJξ + ½νᵀMν − V(n, a) on SO(3) and SO(n), and
the exact flows of the pieces of their Hamiltonian H = ½ΠᵀJ⁻¹Π + ½PᵀM⁻¹P + V(n, a), with the body
momenta Π = Jξ, P = Mν and n = ρ_Q(g)⁻¹q, a = ρ_V(g)⁻¹a₀.

For this ℓ the continuous EP equations (seed 000 eqs. 12–13, 20–21; ``vi_jax.continuous``) read

  Π̇ = ad*_ξΠ + P◇ν − V_a◇a − V_n◇n,   Ṗ = ρ'_Q(ξ)ᵀP − V_n,   ġ = gξ̂,   q̇ = ρ_Q(g)ν,

with ξ = J⁻¹Π, ν = M⁻¹P (on SO(3): ad*_ξΠ = Π×ξ, b◇x = b×x, ρ'_Q(ξ)ᵀP = P×ξ). Each piece is this
system with H replaced by one of its terms, and its flow is exact:

- sphere (SO(3)), H = |Π|²/(2I_s): |Π|² is a Casimir, so Π is constant and ξ = Π/I_s; with
  E = exp(tξ̂), g ← gE and P ← EᵀP (EᵀΠ = Π). With I_s the middle principal moment, the
  rotational energy is this piece plus planar rotations with 1/I_k − 1/I_s about the other two
  axes; the sphere piece commutes with them, and for a symmetric body (I_s repeated) one of
  them vanishes: the free body is then integrated exactly;
- rotation about principal axis k, H = Π_k²/(2I_k): ⟨ad*_ξΠ, e_k⟩ = 0, so Π_k and ξ = (Π_k/I_k)e_k
  are constant and, with E = exp(tξ̂), g ← gE, Π ← Ad*_EΠ (= EᵀΠ on SO(3)), P ← ρ_Q(E)ᵀP; q is
  unchanged. E is a planar rotation: two columns of g and two components of P change
  (McLachlan 1993; Touma & Wisdom 1994; Dullweber, Leimkuhler & McLachlan 1997);
- translation, H = ½PᵀM⁻¹P: ξ = 0 and ν = M⁻¹P constant: P const, Π ← Π + tP◇ν, q ← q + tρ_Q(g)ν;
- potential, H = V(n, a): ξ = ν = 0, so g, q, n, a stay: Π ← Π − t(V_a◇a + V_n◇n), P ← P − tV_n.

Every flow commutes with the left action of the symmetry group on (g, q), so compositions keep the
Kelvin–Noether quantity of ``vi_jax._diagnostics`` (and g on the group) to round-off.

On SO(3), J is diagonalised once, J = U diag(I) Uᵀ with U ∈ SO(3), and the flows run in the
principal frame g' = gU, Π' = UᵀΠ, P' = UᵀP (n' = Uᵀn, a' = Uᵀa). On SO(n) the kinetic energy must
be diagonal in the standard basis of so(n) (each basis element then generates a planar rotation).
The group actions must be the defining representations (``LinearAction(group)``).
"""

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._system import AbstractSystem
from .._xla_flags import loop_option_requested
from ..lie import SO3, SOn
from ..lie._small import matmul, matvec
from ._separability import enforce, hessian_blocks, positive_definite, reference_point, separability_residuals


class Phase(NamedTuple):
    """The state in the principal frame: g' (d×d), q, Π', P' (None without additional dynamics)."""

    g: jax.Array
    q: jax.Array | None
    Pi: jax.Array
    P: jax.Array | None


class SeparableParts(eqx.Module):
    """What the splitting needs of a separable scene: the scene (for V), the principal frame U
    (SO(3); None on SO(n)), the inverse principal moments 1/I_k, M'⁻¹ = UᵀM⁻¹U, whether the scene
    passed the separability check (True, or a traced flag: ``separable_parts(throw=False)``), per algebra
    axis k the plane (i, j) in which exp(θê_k) turns e_i towards e_j and the coordinate pairs
    (m₁, m₂, σ) that Ad*_{exp(θê_k)} rotates, and whether the rotational energy is split with
    the sphere piece (``sphere``: the principal frame then has the middle moment on axis 1)."""

    system: AbstractSystem
    frame: jax.Array | None
    inv_inertia: jax.Array
    inv_mass: jax.Array | None
    separable: jax.Array | bool
    planes: tuple = eqx.field(static=True)
    pairs: tuple = eqx.field(static=True)
    sphere: bool = eqx.field(static=True, default=False)

    @property
    def has_potential(self) -> bool:
        return self.system.has_advected or self.system.has_additional


def _check_group(system):
    G = system.group
    if not isinstance(G, (SO3, SOn)):
        raise ValueError(
            f"system.group: the splitting scheme supports SO3() and SOn(n) scenes, got {type(G).__name__}"
        )
    for name in ("advected_action", "configuration_action"):
        action = getattr(system, name)
        if action is not None and (action.rho is not None or action.group.matrix_size != G.matrix_size):
            raise ValueError(
                f"system.{name}: the splitting scheme needs the defining representation "
                f"LinearAction(group) (its flows rotate body vectors), got {action!r}"
            )


@functools.cache
def _axes(G):
    """Static (planes, pairs) of the algebra axes of G ∈ {SO3, SOn}, from hat(e_k) and ad_{e_k},
    evaluated by one compiled program (op by op, a fresh process's first splitting call compiled
    a program for each of ~25 operations); kept per group: at every call it cost a concrete
    splitting call of the vehicle 9.1 ms outside its program instead of 3.4–3.5 (``python
    benchmarks/call_overhead.py``, default XLA)."""
    basis = np.eye(G.dim)  # a compiled program runs at once, also while a caller is traced
    program = jax.jit(lambda basis: (jax.vmap(G.hat)(basis), jax.vmap(G.ad)(basis))).lower(basis).compile()
    hats, ads = program(basis)
    planes, pairs = [], []
    for hat, ad in zip(np.asarray(hats), np.asarray(ads)):
        (j, i), = np.argwhere(hat > 0.5)  # hat(e_k) = e_j e_iᵀ − e_i e_jᵀ
        planes.append((int(i), int(j)))
        A = ad.T  # Ad*_{exp θê_k} = exp(θ adᵀ_{e_k}), A³ = −A
        pairs.append(tuple((int(m1), int(m2), float(A[m1, m2])) for m1, m2 in np.argwhere(np.triu(np.abs(A) > 0.5))))
    return tuple(planes), tuple(pairs)


@jax.custom_jvp
def principal_axes(J):
    """(U, I) with J = U diag(I) Uᵀ, U ∈ SO(3); the eigenvectors are ordered and signed to be
    closest to the body axes (U = I for a diagonal J, whatever the order of its entries, so the
    splitting is a smooth function of a diagonal J). Its JVP is the first-order perturbation
    formula dU = U(F∘UᵀdJU), F_ij = 1/(I_j − I_i), with F_ij = 0 between equal moments: there
    the principal frame is not unique (nor differentiable); derivatives that keep it are exact."""
    J = 0.5 * (J + J.T)
    d = J.shape[-1]
    w, v = jnp.linalg.eigh(J)
    eye = jnp.eye(d, dtype=v.dtype)
    rows = jnp.argmax(jnp.abs(v), axis=0)
    perm = (rows[None, :] == jnp.arange(d)[:, None]).astype(v.dtype)  # perm[i, k]: eigenvector k ~ axis i
    perm = jnp.where(jnp.all(jnp.sum(perm, axis=1) == 1), perm, eye)
    U, w = matmul(v, perm.T), matvec(perm, w)
    U = U * jnp.where(jnp.diagonal(U) < 0, -1.0, 1.0).astype(U.dtype)
    det = jnp.dot(U[:, 0], jnp.cross(U[:, 1], U[:, 2]))
    flip = jnp.where(det < 0, 1.0 - 2.0 * eye[jnp.argmin(jnp.abs(jnp.diagonal(U)))], 1.0)
    return U * flip.astype(U.dtype), w


@principal_axes.defjvp
def _principal_axes_jvp(primals, tangents):
    (J,), (dJ,) = primals, tangents
    U, w = principal_axes(J)
    B = U.T @ (0.5 * (dJ + dJ.T)) @ U
    gap = w[None, :] - w[:, None]
    same = jnp.abs(gap) <= 64 * jnp.finfo(w.dtype).eps * jnp.max(jnp.abs(w))
    F = jnp.where(same, 0.0, 1.0 / jnp.where(same, 1.0, gap))
    return (U, w), (U @ (F * B), jnp.diagonal(B))


def middle_moment_on_axis_1(U, moments):
    """(U, I) with the principal axes cyclically relabelled (U stays in SO(3), the cross product
    and the planes of the axes are unchanged) so that I_1 is the middle moment: the sphere
    piece's 1/I_s. For a symmetric body that is the repeated moment, whichever of its axes is
    picked."""
    middle = jnp.argsort(moments)[1]
    perm = (middle + 2 + jnp.arange(3)) % 3  # new axis 1 ← old axis ``middle``
    onehot = (perm[None, :] == jnp.arange(3)[:, None]).astype(U.dtype)
    return matmul(U, onehot), matvec(onehot.T, moments)


def _spd_inverse(M):
    """(M⁻¹, a quantity > 0 exactly when the symmetric M is positive definite). For 3×3 the
    adjugate (columns m₁×m₂, m₂×m₀, m₀×m₁ of the rows m_i) and Sylvester's leading minors, a few
    fused elementwise operations instead of a LAPACK factorisation and eigendecomposition per
    call (the set-up of every splitting call of a traced scene)."""
    M = 0.5 * (M + M.T)
    if M.shape != (3, 3):
        return jnp.linalg.inv(M), jnp.linalg.eigvalsh(M)[0]
    adjugate = jnp.stack([jnp.cross(M[1], M[2]), jnp.cross(M[2], M[0]), jnp.cross(M[0], M[1])], axis=1)
    det = jnp.dot(M[0], adjugate[:, 0])
    minors = jnp.stack([M[0, 0], M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0], det])
    return adjugate / det, jnp.min(minors)


@eqx.filter_jit
def _derive(system, dtype, sphere):
    """J, M⁻¹ and the principal frame, and the separability residuals (one compiled function:
    evaluated op by op, the checks cost seconds of dispatch)."""
    G = system.group
    J, M = hessian_blocks(system, *reference_point(system, dtype))
    # The checks need values only: no derivatives of them traced under jax.grad.
    residuals = separability_residuals(*jax.lax.stop_gradient((system, J, M)), diagonal=isinstance(G, SOn))
    J = J.astype(dtype)
    if isinstance(G, SO3):
        U, moments = principal_axes(J)
        if sphere:
            U, moments = middle_moment_on_axis_1(U, moments)
    else:
        U, moments = None, jnp.diagonal(J)
    residuals.append(positive_definite("J = ∂²ℓ/∂ξ²", jax.lax.stop_gradient(jnp.min(moments))))
    inv_mass = None
    if M is not None:
        inv_mass, smallest = _spd_inverse(M.astype(dtype))
        residuals.append(positive_definite("M = ∂²ℓ/∂ν²", jax.lax.stop_gradient(smallest)))
        if U is not None:
            inv_mass = matmul(U.T, matmul(inv_mass, U))
    return U, 1.0 / moments, inv_mass, residuals


def separable_parts(system, dtype=None, *, throw=True, sphere=False) -> SeparableParts:
    """Derive J = ∂²ℓ/∂ξ², M = ∂²ℓ/∂ν² and V = −ℓ(0, n, 0, a) by autodiff, check that ℓ is
    separable (``ValueError`` naming the failing term when the scene is concrete, else a run-time
    ``eqx.error_if``, or with ``throw=False`` the flag ``separable``) and diagonalise J on SO(3)
    (``sphere``: middle moment on axis 1, for the sphere piece); arrays in ``dtype`` (default: float).
    Derivatives with respect to the scene's parameters are those of the splitting of this
    separable ℓ: a parameter that would add a non-separable term (zero at its current value) is
    not seen by them."""
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a vi_jax system (AbstractSystem), got {type(system).__name__}")
    _check_group(system)
    if sphere and not isinstance(system.group, SO3):
        raise ValueError(f"the sphere piece splits the rotational energy on SO3() only, got {system.group!r}")
    dtype = jnp.dtype(jnp.result_type(float) if dtype is None else dtype)
    U, inv_inertia, inv_mass, residuals = _derive(system, dtype, bool(sphere))
    inv_inertia, separable = enforce(residuals, inv_inertia, concrete=val.is_concrete(system), throw=throw)
    planes, pairs = _axes(system.group)
    return SeparableParts(system, U, inv_inertia, inv_mass, separable, planes, pairs, bool(sphere))


# --- the state in the principal frame ----------------------------------------------------------
def to_phase(parts, g, q, M, P) -> Phase:
    """(g, q, Π, P) in the body frame → principal frame: g' = gU, Π' = UᵀΠ, P' = UᵀP."""
    U = parts.frame
    if U is not None:
        g, M = matmul(g, U), matvec(U.T, M)
        P = None if P is None else matvec(U.T, P)
    return Phase(g, q, M, P)


def from_phase(parts, s: Phase):
    """(g, q, Π, P) in the body frame from the principal-frame state (leading axes allowed)."""
    g, M, P = s.g, s.Pi, s.P
    U = parts.frame
    if U is not None:
        g, M = matmul(g, U.T), matvec(U, M)
        P = None if P is None else matvec(U, P)
    return g, s.q, M, P


def velocities(parts, s: Phase):
    """Body velocities ξ = J⁻¹Π and ν = M⁻¹P (body frame; leading axes allowed)."""
    xi = s.Pi * parts.inv_inertia
    nu = None if s.P is None else matvec(parts.inv_mass, s.P)
    U = parts.frame
    if U is not None:
        xi = matvec(U, xi)
        nu = None if nu is None else matvec(U, nu)
    return xi, nu


def _advected(system, g):
    """a' = g'ᵀa₀ as a sum over the nonzero entries of the concrete a₀ (a row of g' for a₀ = e_k)."""
    a0 = np.asarray(system.advected_reference, dtype=np.float64)
    rows = [g[k] if a0[k] == 1.0 else a0[k] * g[k] for k in np.flatnonzero(a0)]
    return sum(rows[1:], rows[0]) if rows else jnp.zeros(g.shape[-1], g.dtype)


# --- the exact flows -----------------------------------------------------------------------------
def potential(parts, n, a):
    """V in the principal frame: V'(n', a') = −ℓ(0, Un', 0, Ua')."""
    system, U = parts.system, parts.frame
    if U is not None:
        n = None if n is None else matvec(U, n)
        a = None if a is None else matvec(U, a)
    dtype = (n if a is None else a).dtype
    nu = None if n is None else jnp.zeros_like(n)
    return -system.lagrangian(jnp.zeros(system.group.dim, dtype), n, nu, a)


def kick(parts, t, s: Phase) -> Phase:
    """Flow of H = V(n, a): Π ← Π − t(V_a◇a + V_n◇n), P ← P − tV_n."""
    system = parts.system
    n = matvec(s.g.T, s.q) if system.has_additional else None
    a = _advected(system, s.g) if system.has_advected else None
    V_n, V_a = jax.grad(lambda n_, a_: potential(parts, n_, a_), argnums=(0, 1))(n, a)
    torque, P = jnp.zeros_like(s.Pi), s.P
    if a is not None:
        torque = torque - system.advected_action.diamond(V_a, a)
    if n is not None:
        torque = torque - system.configuration_action.diamond(V_n, n)
        P = P - t * V_n.astype(P.dtype)
    return Phase(s.g, s.q, s.Pi + t * torque.astype(s.Pi.dtype), P)


def translate(parts, t, s: Phase) -> Phase:
    """Flow of H = ½PᵀM⁻¹P: ν = M⁻¹P, Π ← Π + tP◇ν, q ← q + tg'ν (P constant)."""
    nu = matvec(parts.inv_mass, s.P)
    Pi = s.Pi + t * parts.system.configuration_action.diamond(s.P, nu)
    return Phase(s.g, s.q + t * matvec(s.g, nu), Pi, s.P)


def _planar_increment(cm1, sn, pairs, size):
    """A − 1 for the matrix A with (Av)_a = c v_a + σ sn v_b, (Av)_b = c v_b − σ sn v_a for each
    (a, b, σ) of ``pairs`` (identity elsewhere), c = 1 + ``cm1``: a rotation of those coordinate
    planes, applied as v + (A − 1)v. Built from constant masks and applied as a small product,
    which XLA:CPU fuses (indexing the turned entries instead measured 2–4× slower per step)."""
    diag, skew = np.zeros((size, size)), np.zeros((size, size))
    for a, b, sigma in pairs:
        diag[a, a] = diag[b, b] = 1.0
        skew[a, b], skew[b, a] = sigma, -sigma
    return cm1 * diag.astype(cm1.dtype) + sn * skew.astype(cm1.dtype)


# Rotations are applied as increments, v ← v + ((c − 1)v + s w), with c − 1 computed to full
# relative precision (never as cos θ rounded to a number near 1, then minus 1). A scene can turn
# by the same angle step after step (the symmetric top: Π₃ and |Π| are constant), and then the
# rounding of c, the same at every step, would scale g by the same 1 + O(ε) every time: a drift
# off SO(3) (4e-10 after 10⁶ heavy-top steps, against a random walk's 6e-12). In increments the
# scale error is O(θ²ε) and the roundings of v + … vary with v: a random walk.
#
# 1 − cos θ = u·C(u) and sin θ = θ + θu·S(u), u = θ², with the Taylor polynomials C and S of 9
# terms (remainders for |θ| ≤ 1 below 1/20! ≈ 4e-19) evaluated by Estrin's scheme; θ is added
# last, so sin θ is rounded about as a correctly rounded sin is.
_COS_TAIL = tuple((-1) ** k / math.factorial(2 * k + 2) for k in range(9))
_SIN_TAIL = tuple((-1) ** (k + 1) / math.factorial(2 * k + 3) for k in range(9))


def _estrin(a, u):
    """Σ a_k u^k (9 coefficients) with a dependency depth of 5 operations rather than Horner's 9."""
    u2 = u * u
    u4 = u2 * u2
    q = [a[k] + a[k + 1] * u for k in range(0, 8, 2)]
    return (q[0] + q[1] * u2) + (q[2] + q[3] * u2) * u4 + a[8] * (u4 * u4)


def _cos_minus_one_sin_small(theta):
    u = theta * theta
    return -(u * _estrin(_COS_TAIL, u)), theta + (theta * u) * _estrin(_SIN_TAIL, u)


def _cos_minus_one_sin_trig(theta):
    """cos θ − 1 = −2 sin²(θ/2) and sin θ = 2 sin(θ/2) cos(θ/2), each to full relative precision."""
    half_sin, half_cos = jnp.sin(0.5 * theta), jnp.cos(0.5 * theta)
    return -2 * half_sin * half_sin, 2 * half_sin * half_cos


def _cos_minus_one_sin(theta, loop_option):
    """cos θ − 1 and sin θ. The stages of a splitting are one chain of dependent rotations, so
    under XLA:CPU's loop option (one kernel per loop) a step costs the latency of its sines and
    cosines: there |θ| ≤ 1 (every rotation of a resolved run) takes the polynomials above behind
    a ``lax.cond`` (same values to round-off). Without the option each conditional is a dispatch
    of its own and costs more than it saves, so the half-angle trig runs."""
    if not loop_option:
        return _cos_minus_one_sin_trig(theta)
    return jax.lax.cond(jnp.abs(theta) <= 1, _cos_minus_one_sin_small, _cos_minus_one_sin_trig, theta)


def _turn_columns(x, i, j, cm1, s):
    """x with columns i, j replaced by x_i + ((c − 1)x_i + s x_j) and x_j + ((c − 1)x_j − s x_i)
    (x E for the planar E)."""
    xi, xj = x[:, i], x[:, j]
    new = {i: xi + (cm1 * xi + s * xj), j: xj + (cm1 * xj - s * xi)}
    return jnp.stack([new.get(m, x[:, m]) for m in range(x.shape[1])], axis=1)


def rotate(parts, k, t, s: Phase) -> Phase:
    """Flow of H = Π_k²/(2I_k) (with the sphere piece: Π_k²(1/I_k − 1/I_1)/2): a planar
    rotation E = exp(tω ê_k), ω = Π_k/I_k, of g' (g' ← g'E), Π' (← Ad*_EΠ') and P' (← EᵀP').
    In the plane (i, j) of ê_k, Ee_i = c e_i + s e_j and Ee_j = c e_j − s e_i. On SO(3),
    Ad*_EΠ = EᵀΠ: the rows of g', Π'ᵀ and P'ᵀ are turned together: by one small product with
    XLA's default flags (1.4–1.9× faster per step than a product each), column by column under
    the loop option (1.3–1.5× faster there than the product, 1.2–1.6× slower than it without the
    option): ``python benchmarks/splitting_rotation.py [--fast-loops]``."""
    loop_option = loop_option_requested()
    rate = parts.inv_inertia[k] - parts.inv_inertia[1] if parts.sphere else parts.inv_inertia[k]
    cm1, sn = _cos_minus_one_sin(t * (s.Pi[k] * rate), loop_option)
    i, j = parts.planes[k]
    if parts.frame is not None:
        rows = jnp.concatenate([s.g, s.Pi[None]] + ([] if s.P is None else [s.P[None]]))
        if loop_option:
            rows = _turn_columns(rows, i, j, cm1, sn)
        else:
            rows = rows + matmul(rows, _planar_increment(cm1, sn, ((i, j, 1.0),), 3).T)
        return Phase(rows[:3], s.q, rows[3], None if s.P is None else rows[4])
    Dt = _planar_increment(cm1, sn, ((i, j, 1.0),), s.g.shape[-1])
    P = None if s.P is None else s.P + matvec(Dt, s.P)
    Pi = s.Pi + matvec(_planar_increment(cm1, sn, parts.pairs[k], s.Pi.shape[-1]), s.Pi)
    return Phase(s.g + matmul(s.g, Dt.T), s.q, Pi, P)


def _sphere_coefficients(u, loop_option):
    """(sin θ/θ, (1 − cos θ)/θ²) from u = θ²: the polynomials of ``_cos_minus_one_sin_small``
    for u ≤ 1 (no square root, no trig; behind a ``lax.cond`` under the loop option, as in
    :func:`_cos_minus_one_sin`), else from θ = √u (safe for both values and derivatives at
    u = 0)."""
    small = lambda u: (1 + u * _estrin(_SIN_TAIL, u), _estrin(_COS_TAIL, u))  # noqa: E731

    def large(u):
        theta = jnp.sqrt(jnp.where(u > 1, u, 1.0))
        return jnp.sin(theta) / theta, (1 - jnp.cos(theta)) / (theta * theta)

    if loop_option:
        return jax.lax.cond(u <= 1, small, large, u)
    (a_small, b_small), (a_large, b_large) = small(jnp.minimum(u, 1.0)), large(u)
    return jnp.where(u <= 1, a_small, a_large), jnp.where(u <= 1, b_small, b_large)


def sphere(parts, t, s: Phase) -> Phase:
    """Flow of H = |Π'|²/(2I_1) on SO(3): Π' constant, E = exp(φ̂), φ = tΠ'/I_1 (Rodrigues:
    E = 1 + Aφ̂ + Bφ̂², A = sin θ/θ, B = (1 − cos θ)/θ², θ = |φ|); g' ← g'E, P' ← EᵀP'
    (the rows of g' and P'ᵀ turned together). Under the loop option by cross products, else by
    one small product with E (each 1.2–1.3× faster per vehicle step than the other there:
    1.25 against 1.51 µs, 5.8 against 7.5 µs at order 6)."""
    loop_option = loop_option_requested()
    phi = t * parts.inv_inertia[1] * s.Pi
    u = jnp.sum(phi * phi)
    A, B = _sphere_coefficients(u, loop_option)
    rows = s.g if s.P is None else jnp.concatenate([s.g, s.P[None]])
    if loop_option:  # rE = r + A r×φ + B (r×φ)×φ
        r_phi = jnp.cross(rows, phi)
        rows = rows + A * r_phi + B * jnp.cross(r_phi, phi)
    else:  # E − 1 = Bφφᵀ − Bθ²·1 + Aφ̂ (φ̂² = φφᵀ − θ²·1), entry by entry; rows + rows(E − 1)
        D = B * phi[:, None] * phi[None, :] - (B * u) * jnp.eye(3, dtype=phi.dtype) + A * SO3().hat(phi)
        rows = rows + matmul(rows, D)
    return Phase(rows[:3], s.q, s.Pi, None if s.P is None else rows[3])


def piece_flows(parts):
    """{name: flow(t, phase)} of the pieces present in the scene: "V" (potential), "T"
    (translation), and one rotation per principal axis 0, 1, … (with the sphere piece "S":
    axes 0 and 2 only)."""
    flows = {}
    if parts.has_potential:
        flows["V"] = lambda t, s: kick(parts, t, s)
    if parts.system.has_additional:
        flows["T"] = lambda t, s: translate(parts, t, s)
    if parts.sphere:
        flows["S"] = lambda t, s: sphere(parts, t, s)
    for k in range(parts.system.group.dim):
        if not (parts.sphere and k == 1):
            flows[k] = lambda t, s, k=k: rotate(parts, k, t, s)
    return flows
