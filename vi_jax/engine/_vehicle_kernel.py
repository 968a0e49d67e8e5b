"""The batched underwater-vehicle kernel behind ``vj.ensemble(method="batched")``: the paper's
first-order rule (seed 000 eqs. 73–74 with 88 for Cayley, 97 for exp) on *component arrays* of
shape (members,), so every operation of a step is an elementwise loop over the members and XLA
fuses a whole Newton iteration into one vectorised loop. The Newton machinery (Jacobian by
forward mode, unrolled LU, masked fallback iterations, implicit-function gradients) is generic in
the residual; only the step itself is written for the vehicle."""

import jax
import jax.numpy as jnp

from ..solvers import MAX_ITERATIONS, NONFINITE, SINGULAR_DIFFERENCE_MAP, SUCCESS, CHORD_ITERATIONS
from ..lie import _series
from .._saved_nodes import SAVE_BLOCK, rematerialised_steps, scan_saved_nodes
from ._solution import Solution


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


def _vmax(v):
    out = v[0]
    for x in v[1:]:
        out = jnp.maximum(out, x)
    return out


def _lu(A):
    """Unrolled LU factors of a small k×k matrix, without pivoting (as ``_solve.dense_solve``:
    the Newton matrices are h-perturbations of a positive definite Hessian)."""
    rows = [list(row) for row in A]
    k = len(rows)
    inv_diag, multipliers = [], []
    for j in range(k):
        inv_diag.append(1 / rows[j][j])
        col = []
        for i in range(j + 1, k):
            f = rows[i][j] * inv_diag[j]
            rows[i] = [rows[i][c] - f * rows[j][c] for c in range(k)]
            col.append(f)
        multipliers.append(col)
    return rows, inv_diag, multipliers


def _lu_solve(lu, b):
    rows, inv_diag, multipliers = lu
    k = len(b)
    y = list(b)
    for j in range(k):
        for f, i in zip(multipliers[j], range(j + 1, k)):
            y[i] = y[i] - f * y[j]
    x = [None] * k
    for i in reversed(range(k)):
        acc = y[i]
        for c in range(i + 1, k):
            acc = acc - rows[i][c] * x[c]
        x[i] = acc * inv_diag[i]
    return tuple(x)


def _columns(linear, like):
    """Per-member Jacobian of a map with no coupling between members: column j is the map
    applied to the tangent with component j = 1 for every member."""
    k = len(like)
    cols = [linear(tuple(jnp.ones_like(c) if i == j else jnp.zeros_like(c) for i, c in enumerate(like))) for j in range(k)]
    return [[cols[j][i] for j in range(k)] for i in range(k)]


def _where(mask, new, old):
    return jax.tree.map(lambda a, b: jnp.where(mask, a, b), new, old)


def newton_members(fn, z0, *, rtol, max_iterations, chord_iterations=CHORD_ITERATIONS):
    """Solve ``fn(z) = 0`` for every member at once; ``z`` is a tuple of component arrays and
    ``fn(z) -> (residual, scale)`` (same tuple structure; scale per member) must not couple
    members. The iteration of ``vj.simulate``'s Newton (one Newton step, chord steps, a check,
    masked fallback Newton steps while any member has not converged, a final correction).
    Returns z and per-member (iterations, relative residual, result); implicit-function
    gradients through ``jax.lax.custom_root``."""

    def residual_only(z):
        return fn(z)[0]

    def norm(r):
        return _vmax(tuple(jnp.abs(c) for c in r))

    def not_converged(r, scale):
        return norm(r) > rtol * scale

    def finite(r):
        out = jnp.isfinite(r[0])
        for c in r[1:]:
            out = out & jnp.isfinite(c)
        return out

    def value_and_lu(z):
        r, scale = fn(z)
        _, lin = jax.linearize(residual_only, z)
        return r, scale, _lu(_columns(lin, z))

    def solve(_, z):
        r, scale, lu = value_and_lu(z)
        n_chord = max(min(chord_iterations, max_iterations - 1), 0)
        for _ in range(1 + n_chord):
            z = _axpy(-1.0, _lu_solve(lu, r), z)
            r, scale = fn(z)
        i = jnp.full(jnp.shape(scale), 1 + n_chord, jnp.int32)

        def active_of(i, r, scale):
            return (i < max_iterations) & not_converged(r, scale) & finite(r)

        def body(state):
            i, z, r, scale, lu, active = state
            z = _where(active, _axpy(-1.0, _lu_solve(lu, r), z), z)
            new = value_and_lu(z)
            r, scale, lu = _where(active, new, (r, scale, lu))
            i = i + active
            return i, z, r, scale, lu, active_of(i, r, scale)

        state = (i, z, r, scale, lu, active_of(i, r, scale))
        state = jax.lax.cond(
            jnp.any(state[-1]),
            lambda s: jax.lax.while_loop(lambda s: jnp.any(s[-1]), body, s),
            lambda s: s,
            state,
        )
        i, z, r, scale, lu, _ = state
        z = _axpy(-1.0, _lu_solve(lu, r), z)
        rel = norm(r) / jnp.where(scale > 0, scale, 1.0)
        ok = finite(z) & finite(r)
        result = jnp.where(~ok, NONFINITE, jnp.where(rel <= rtol, SUCCESS, MAX_ITERATIONS))
        dtype = z[0].dtype  # custom_root's JVP rule mishandles integer auxiliary outputs
        return z, (i.astype(dtype), rel, result.astype(dtype))

    def tangent_solve(linear, y):
        return _lu_solve(_lu(_columns(linear, y)), y)

    z, (i, rel, result) = jax.lax.custom_root(residual_only, z0, solve, tangent_solve, has_aux=True)
    stats = (i.astype(jnp.int32), rel, result.astype(jnp.int8))
    return z, jax.lax.stop_gradient(stats)


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
        return tuple(a - b for a, b in zip(f, rhs)), _vmax(tuple(jnp.abs(c) + s for c, s in zip(f, size)))

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


def _no_stats(n_members, dtype):
    return (jnp.zeros((n_members,), jnp.int32), jnp.zeros((n_members,), dtype), jnp.zeros((n_members,), jnp.int8))


def _pack(state, stats, dtype):
    """One packed row per node: a write per saved array costs more than the arithmetic."""
    return jnp.stack(jax.tree.leaves(state[:4])), jnp.stack([x.astype(dtype) for x in stats])


def _vehicle_batched(system, x0, h, n_saved, save_every, tau, rtol, max_iterations, n_members, checkpoint):
    """Solution of every member (leading axis = member) from the batch-minor kernel (static
    step counts: what ``jit``, ``grad`` and ``vmap`` trace). ``checkpoint``: reverse mode
    rematerialises as ``vj.simulate``'s (states stored at blocks of saved nodes, √save_every
    blocks of steps between two nodes); the forward pass is unchanged."""
    p, dtype, state0, worst_step = _vehicle_start(system, x0, h, tau, rtol, max_iterations, n_members)

    def worst_steps(carry, n):
        return jax.lax.scan(worst_step, carry, None, length=n)[0]

    def node(state, _):
        carry = (state, _no_stats(n_members, dtype))
        if not checkpoint or save_every <= SAVE_BLOCK:
            carry = worst_steps(carry, save_every)
        else:
            carry = rematerialised_steps(worst_steps, carry, save_every)
        return carry[0], _pack(*carry, dtype)

    _, (saved, stats) = scan_saved_nodes(node, state0, n_saved, checkpoint)
    return _vehicle_solution(p, state0, saved, stats, h * save_every, n_members, dtype)


def _vehicle_loop(system, x0, h, n_saved, save_every, capacity, tau, rtol, max_iterations, n_members):
    """The same with traced step counts (``n_saved`` ≤ ``capacity`` nodes of ``save_every``
    steps): one program for every run length. Rows past ``n_saved`` repeat the initial state."""
    p, dtype, state0, worst_step = _vehicle_start(system, x0, h, tau, rtol, max_iterations, n_members)
    first, no_stats = _pack(state0, _no_stats(n_members, dtype), dtype)

    def node(k, carry):
        state, saved, stats = carry
        carry = jax.lax.fori_loop(0, save_every, lambda _, c: worst_step(c, None)[0], (state, _no_stats(n_members, dtype)))
        row, row_stats = _pack(*carry, dtype)
        return carry[0], saved.at[k].set(row), stats.at[k].set(row_stats)

    buffers = (jnp.broadcast_to(first, (capacity,) + first.shape), jnp.broadcast_to(no_stats, (capacity,) + no_stats.shape))
    _, saved, stats = jax.lax.fori_loop(0, n_saved, node, (state0, *buffers))
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
