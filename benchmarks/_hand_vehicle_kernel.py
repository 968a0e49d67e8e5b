"""The underwater vehicle's batched step written by hand, the peer of the generated step in the
ensemble benchmarks (``vj.ensemble`` ran it for the vehicle at order 1 until the generated step
replaced it: nothing behind ``vj.ensemble`` names a model). The paper's first-order rule (seed
000 eqs. 73–74 with 88 for Cayley, 97 for exp) on *component arrays* of shape (members,), so
every operation of a step is an elementwise loop over the members; ν is explicit (eq. 74),
``M⁻¹`` is formed once per run and the right-hand side of eq. 73 once per step, Newton (the engine's
:func:`~vi_jax.engine._member_newton.newton_members`) runs on ω alone.

    hand_kernel_ensemble(system, x0, h, n_steps, save_every=..., system_axes=None)  # jittable
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from vi_jax import Solution
from vi_jax.engine._member_loops import scan_member_nodes
from vi_jax.engine._simulate import _default_rtol
from vi_jax.engine._member_newton import newton_members, vmax
from vi_jax.engine._member_split import CHUNK, in_chunks, leaf_axes, member_counts
from vi_jax.lie import _series
from vi_jax.solvers import SINGULAR_DIFFERENCE_MAP, SUCCESS


# --- component-array ("structure of arrays") algebra ------------------------------------
# A vector is a tuple of component arrays (each of shape (members,) or a broadcastable scalar);
# a matrix is a tuple of row tuples.


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _axpy(s, x, y):
    """s·x + y."""
    return tuple(s * a + b for a, b in zip(x, y))


def _matvec(A, v):
    return tuple(_dot(row, v) for row in A)


def _tmatvec(A, v):
    return tuple(A[0][j] * v[0] + A[1][j] * v[1] + A[2][j] * v[2] for j in range(3))


def _matmul(A, B):
    return tuple(tuple(A[i][0] * B[0][j] + A[i][1] * B[1][j] + A[i][2] * B[2][j] for j in range(3)) for i in range(3))


def _inv3(A):
    """Closed-form inverse (adjugate / determinant)."""
    c = (_cross(A[1], A[2]), _cross(A[2], A[0]), _cross(A[0], A[1]))
    inv_det = 1 / _dot(A[0], c[0])
    return tuple(tuple(c[j][i] * inv_det for j in range(3)) for i in range(3))


# --- the underwater vehicle on component arrays -----------------------------------------


def _dtau_dual(tau, h, w, mu):
    """(dτ⁻¹_{hω})* μ on component arrays: μ + (h/2)ω×μ + (h²/4)(ω·μ)ω for Cayley (eq. 88),
    μ + (h/2)ω×μ + h²α(h|ω|)ω×(ω×μ) for exp (eq. 97)."""
    wxmu = _cross(w, mu)
    if tau == "cayley":
        last = tuple(0.25 * h**2 * _dot(w, mu) * c for c in w)
    else:
        alpha = _series.dexp_inv_alpha(h**2 * _dot(w, w))
        last = tuple(h**2 * alpha * c for c in _cross(w, wxmu))
    return tuple(m + 0.5 * h * a + b for m, a, b in zip(mu, wxmu, last))


def _group_map(tau, x):
    """τ(x̂): cay(x) = I + 4/(4+|x|²)(x̂ + x̂²/2) or Rodrigues' exp, with x̂² = xxᵀ − |x|²I."""
    t2 = _dot(x, x)
    if tau == "cayley":
        a = 4 / (4 + t2)
        b = 0.5 * a
    else:
        a, b = _series.sinc(t2), _series.one_minus_cos_over_t2(t2)
    X = ((0.0, -x[2], x[1]), (x[2], 0.0, -x[0]), (-x[1], x[0], 0.0))
    return tuple(
        tuple((i == j) + a * X[i][j] + b * (x[i] * x[j] - (i == j) * t2) for j in range(3)) for i in range(3)
    )


def _vehicle_parameters(system, dtype):
    """Parameters as components: scalars, or arrays over the members."""
    c = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    m = c(system.mass)
    A = c(system.added_mass)
    J = c(system.inertia)
    # ℓ depends on the symmetric parts only: so do the steps and their gradients.
    sym = lambda X, i, j: 0.5 * (X[..., i, j] + X[..., j, i])  # noqa: E731
    mass = tuple(tuple(m * (i == j) + sym(A, i, j) for j in range(3)) for i in range(3))
    inertia = tuple(tuple(sym(J, i, j) for j in range(3)) for i in range(3))
    B = c(system.buoyancy)
    r = c(system.buoyancy_offset)
    return dict(
        mass=mass, mass_inv=_inv3(mass), inertia=inertia, inertia_inv=_inv3(inertia),
        weight=m * c(system.gravity), buoyancy=B, offset=tuple(r[..., i] for i in range(3)),
    )


def _vehicle_step(p, tau, h, rtol, max_iterations, state):
    """One step of eqs. (73)–(74): ν_k explicit, ω_k by Newton, for every member at once."""
    R, q, M, P, w = state
    a = R[2]  # Rᵀe_z
    Mnu = _axpy(h * (p["weight"] - p["buoyancy"]), a, P)  # eq. (74)
    nu = _matvec(p["mass_inv"], Mnu)
    torque = tuple(-h * p["buoyancy"] * c for c in _cross(p["offset"], a))
    munk = tuple(h * c for c in _cross(Mnu, nu))
    rhs = tuple(m + t + k for m, t, k in zip(M, torque, munk))  # eq. (73)
    size = tuple(jnp.abs(t) + jnp.abs(k) for t, k in zip(torque, munk))

    def residual(w):
        f = _dtau_dual(tau, h, w, _matvec(p["inertia"], w))
        return tuple(a - b for a, b in zip(f, rhs)), vmax(tuple(jnp.abs(c) + s for c, s in zip(f, size)))

    w, (iterations, rel, result) = newton_members(residual, w, rtol=rtol, max_iterations=max_iterations)
    if tau == "exp":
        result = jnp.where(h**2 * _dot(w, w) < jnp.pi**2, result, jnp.int8(SINGULAR_DIFFERENCE_MAP))
    lam = _group_map(tau, tuple(h * c for c in w))
    new = (
        _matmul(R, lam),
        _axpy(h, _matvec(R, nu), q),
        _dtau_dual(tau, -h, w, _matvec(p["inertia"], w)),
        _tmatvec(lam, Mnu),
        w,
    )
    return new, (iterations, rel, result)


def _vehicle_diagnostics(p, R, q, M, P):
    """Node velocities (continuous inverse Legendre map), energy and Kelvin–Noether quantity,
    as ``vj.simulate`` computes them, on component arrays."""
    omega = _matvec(p["inertia_inv"], M)
    nu = _matvec(p["mass_inv"], P)
    n = _tmatvec(R, q)
    a = R[2]
    energy = 0.5 * (_dot(omega, M) + _dot(nu, P)) - (p["weight"] - p["buoyancy"]) * _dot(n, a)
    energy = energy + p["buoyancy"] * _dot(p["offset"], a)
    kn = _dot(a, _axpy(-1.0, _cross(P, n), M))  # e_zᵀR(M − P◇n), P◇n = P×n
    kn_scale = jnp.sqrt(_dot(M, M)) + jnp.sqrt(_dot(P, P)) * jnp.sqrt(_dot(n, n))
    return omega, nu, energy, kn, kn_scale


def _stack(v):
    """Component tuple → array with the components last (a matrix's rows, then columns)."""
    if isinstance(v[0], tuple):
        return jnp.stack([jnp.stack(row, axis=-1) for row in v], axis=-2)
    return jnp.stack(v, axis=-1)


def _vehicle_start(system, x0, h, tau, rtol, max_iterations, n_members):
    """(parameters, dtype, initial state, ``worst_step``): the step carrying the worst Newton
    statistics since the last saved node, ``((state, worst), _) -> ((state, worst), None)``."""
    dtype = jnp.asarray(h).dtype
    p = _vehicle_parameters(system, dtype)
    full = lambda x: jnp.broadcast_to(jnp.asarray(x, dtype), (n_members,))  # noqa: E731
    R0 = tuple(tuple(full(x0.g[..., i, j]) for j in range(3)) for i in range(3))
    omega0 = tuple(full(x0.xi[..., i]) for i in range(3))
    q0 = tuple(full(x0.q[..., i]) for i in range(3))
    v0 = tuple(full(x0.qdot[..., i]) for i in range(3))
    state0 = (R0, q0, _matvec(p["inertia"], omega0), _matvec(p["mass"], _tmatvec(R0, v0)), omega0)

    def worst_step(carry, _):
        state, worst = carry
        state, stats = _vehicle_step(p, tau, h, rtol, max_iterations, state)
        return (state, jax.tree.map(jnp.maximum, worst, stats)), None

    return p, dtype, state0, worst_step


def _rows(state):
    return jax.tree.leaves(state[:4])


def _vehicle_batched(system, x0, h, n_saved, save_every, tau, rtol, max_iterations, n_members, checkpoint):
    """Solution of every member (leading axis = member), static step counts."""
    p, dtype, state0, worst_step = _vehicle_start(system, x0, h, tau, rtol, max_iterations, n_members)
    saved, stats = scan_member_nodes(worst_step, state0, _rows, n_saved, save_every, checkpoint, n_members, dtype)
    return _vehicle_solution(p, state0, saved, stats, h * save_every, n_members, dtype)


def _vehicle_solution(p, state0, saved, stats, dt_saved, n_members, dtype):
    """The Solution from the packed rows of the saved nodes (the initial state prepended)."""
    n_saved = saved.shape[0]
    saved = jnp.concatenate([jnp.stack(jax.tree.leaves(state0[:4]))[None], saved])
    R, q, M, P = jax.tree.unflatten(jax.tree.structure(state0[:4]), list(jnp.moveaxis(saved, 1, 0)))
    omega, nu, energy, kn, kn_scale = _vehicle_diagnostics(p, R, q, M, P)
    iterations, rel, result = (
        jnp.concatenate([jnp.full((1, n_members), v, t), x.astype(t)])
        for v, x, t in zip((0, 0, SUCCESS), jnp.moveaxis(stats, 1, 0), (jnp.int32, dtype, jnp.int8))
    )
    members_first = lambda x: jnp.moveaxis(x, 1, 0)  # noqa: E731  (nodes, members, …) → (members, nodes, …)
    return Solution(
        t=jnp.broadcast_to(dt_saved * jnp.arange(n_saved + 1, dtype=dtype), (n_members, n_saved + 1)),
        g=members_first(_stack(R)),
        xi=members_first(_stack(omega)),
        q=members_first(_stack(q)),
        nu=members_first(_stack(nu)),
        M=members_first(_stack(M)),
        P=members_first(_stack(P)),
        energy=members_first(energy),
        kelvin_noether=members_first(kn),
        kelvin_noether_scale=members_first(kn_scale),
        newton_iterations=members_first(iterations),
        newton_residual=members_first(rel),
        result=members_first(result),
    )


def hand_kernel_ensemble(system, x0, h, n_steps, *, save_every=1, system_axes=None, x0_axes=0, tau="cayley",
                         rtol=None, max_newton_iterations=20, checkpoint=True, chunk=CHUNK):
    """The vehicle at order 1 for every member (leading axis = member), as ``vj.ensemble`` with
    ``method="batched"`` on CPU ran it: chunks of ``chunk`` members one after another."""
    dtype = jnp.result_type(x0.g, h)
    h = jnp.asarray(h, dtype)
    rtol = _default_rtol(dtype) if rtol is None else float(rtol)
    axes = (leaf_axes("system_axes", system, system_axes), leaf_axes("x0_axes", x0, x0_axes))
    (n_members,) = set(member_counts("system_axes", system, axes[0]) + member_counts("x0_axes", x0, axes[1]))
    dynamic, static = eqx.partition((system, x0), eqx.is_array)

    def kernel(system, x0, n):
        return _vehicle_batched(system, x0, h, n_steps // save_every, save_every, tau, rtol, max_newton_iterations, n, checkpoint)

    return in_chunks(dynamic, static, axes, n_members, chunk, kernel)
