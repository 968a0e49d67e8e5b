"""Newton's method for every member of an ensemble at once, on component arrays: the unknowns
are a tuple of arrays over the members, nothing couples two members. The iteration is
``vj.simulate``'s (:func:`vi_jax.solvers.newton_root`): one Newton step, chord steps, a check,
masked fallback Newton steps while some member has not converged, a final correction;
implicit-function gradients through ``jax.lax.custom_root``.

The Jacobian's entries may be known constants or scalars shared by all members (the generated
step's forward-mode Jacobian keeps them so: e.g. ∂P/∂ξ = 0 and ∂P/∂ν = M for a separable
scene); the unrolled LU below folds them, so only the entries that differ per member cost
work per member.
"""

import jax
import jax.numpy as jnp

from ..solvers import CHORD_ITERATIONS, MAX_ITERATIONS, NONFINITE, SUCCESS
from ._components import fold_mul, fold_sub, from_member_arrays, member_arrays


def vmax(v):
    out = v[0]
    for x in v[1:]:
        out = jnp.maximum(out, x)
    return out


def lu(A):
    """Unrolled LU factors of a small k×k matrix, without pivoting (as ``dense_solve``: the
    Newton matrices are h-perturbations of a positive definite Hessian)."""
    rows = [list(row) for row in A]
    k = len(rows)
    inv_diag, multipliers = [], []
    for j in range(k):
        inv_diag.append(1 / rows[j][j])
        col = []
        for i in range(j + 1, k):
            f = fold_mul(rows[i][j], inv_diag[j])
            rows[i] = [fold_sub(rows[i][c], fold_mul(f, rows[j][c])) for c in range(k)]
            col.append(f)
        multipliers.append(col)
    return rows, inv_diag, multipliers


def lu_solve(factors, b):
    rows, inv_diag, multipliers = factors
    k = len(b)
    y = list(b)
    for j in range(k):
        for f, i in zip(multipliers[j], range(j + 1, k)):
            y[i] = fold_sub(y[i], fold_mul(f, y[j]))
    x = [None] * k
    for i in reversed(range(k)):
        acc = y[i]
        for c in range(i + 1, k):
            acc = fold_sub(acc, fold_mul(rows[i][c], x[c]))
        x[i] = fold_mul(acc, inv_diag[i])
    return tuple(x)


def columns(linear, like):
    """Per-member Jacobian of a map with no coupling between members: column j is the map
    applied to the tangent with component j = 1 for every member."""
    k = len(like)
    cols = [linear(tuple(jnp.ones_like(c) if i == j else jnp.zeros_like(c) for i, c in enumerate(like))) for j in range(k)]
    return [[cols[j][i] for j in range(k)] for i in range(k)]


def value_and_jacobian_of(residual, argnum):
    """``residual(*args) -> (r, scale)`` ↦ ``(*args) -> (r, scale, ∂r/∂args[argnum])``, the
    Jacobian by forward mode (a per-member function, to run on components)."""

    def value_and_jacobian(*args):
        def with_aux(z):
            r, scale = residual(*args[:argnum], z, *args[argnum + 1 :])
            return r, (r, scale)

        jac, (r, scale) = jax.jacfwd(with_aux, has_aux=True)(args[argnum])
        return r, scale, jac

    return value_and_jacobian


def on_member_tuples(residual, value_and_jacobian, shape, n_members, dtype, boundary=lambda tree: tree):
    """:func:`newton_members`'s ``fn`` and ``value_and_jacobian`` from functions of the unknowns
    as components (an object array of ``shape``). Jacobian entries that are constants or shared
    by all members stay so: the LU folds them. ``boundary`` marks the residuals and Jacobians
    (the iterates need none: what reads them several times, the momentum, is marked shared)."""

    def values(r, scale):
        return member_arrays(r, n_members, dtype), jnp.broadcast_to(scale[()], (n_members,))

    def fn(zt):
        return boundary(values(*residual(from_member_arrays(zt, shape))))

    def fn_jac(zt):
        r, scale, jac = value_and_jacobian(from_member_arrays(zt, shape))
        return boundary(values(r, scale) + (tuple(tuple(row) for row in jac),))

    return fn, fn_jac


def _where(mask, new, old):
    return jax.tree.map(lambda a, b: jnp.where(mask, a, b), new, old)


def _axpy(s, x, y):
    """s·x + y."""
    return tuple(s * a + b for a, b in zip(x, y))


def newton_members(fn, z0, *, rtol, max_iterations, chord_iterations=CHORD_ITERATIONS, value_and_jacobian=None):
    """Solve ``fn(z) = 0`` for every member at once; ``z`` is a tuple of member arrays and
    ``fn(z) -> (residual, scale)`` (same tuple structure; scale per member) must not couple
    members. ``value_and_jacobian(z) -> (residual, scale, rows)`` gives the Jacobian (default:
    forward mode through ``fn``, column by column). Returns z and per-member (iterations,
    relative residual, result)."""

    def residual_only(z):
        return fn(z)[0]

    def norm(r):
        return vmax(tuple(jnp.abs(c) for c in r))

    def not_converged(r, scale):
        return norm(r) > rtol * scale

    def finite(r):
        out = jnp.isfinite(r[0])
        for c in r[1:]:
            out = out & jnp.isfinite(c)
        return out

    def value_and_jacobian_rows(z):
        if value_and_jacobian is not None:
            return value_and_jacobian(z)
        r, scale = fn(z)
        _, lin = jax.linearize(residual_only, z)
        return r, scale, columns(lin, z)

    def value_and_lu(z):
        r, scale, jac = value_and_jacobian_rows(z)
        return r, scale, lu(jac)

    def solve(_, z):
        r, scale, jac = value_and_jacobian_rows(z)
        factors = lu(jac)
        if all(jnp.ndim(entry) == 0 for row in jac for entry in row):
            # No Jacobian entry is a member array, so none depends on z: fn is affine and one
            # Newton step solves it (e.g. the inverse Legendre map of a kinetic energy quadratic
            # in the velocities); one more step with the same factors refines it. No loop and
            # no fallback to compile.
            z = _axpy(-1.0, lu_solve(factors, r), z)
            r, scale = fn(z)
            return _finish(jnp.ones(jnp.shape(scale), jnp.int32), _axpy(-1.0, lu_solve(factors, r), z), r, scale)
        n_chord = max(min(chord_iterations, max_iterations - 1), 0)
        for _ in range(1 + n_chord):
            z = _axpy(-1.0, lu_solve(factors, r), z)
            r, scale = fn(z)
        i = jnp.full(jnp.shape(scale), 1 + n_chord, jnp.int32)

        def active_of(i, r, scale):
            return (i < max_iterations) & not_converged(r, scale) & finite(r)

        def body(state):
            i, z, r, scale, factors, active = state
            z = _where(active, _axpy(-1.0, lu_solve(factors, r), z), z)
            new = value_and_lu(z)
            r, scale, factors = _where(active, new, (r, scale, factors))
            i = i + active
            return i, z, r, scale, factors, active_of(i, r, scale)

        def fallback(state):
            # Folded (constant or shared) LU entries become member arrays: a loop carry.
            as_members = lambda x: jnp.broadcast_to(jnp.asarray(x, z[0].dtype), jnp.shape(z[0]))  # noqa: E731
            i, z_, r, scale = state
            loop = (i, z_, r, scale, jax.tree.map(as_members, factors), active_of(i, r, scale))
            i, z_, r, scale, last, _ = jax.lax.while_loop(lambda s: jnp.any(s[-1]), body, loop)
            return i, _axpy(-1.0, lu_solve(last, r), z_), r, scale

        def common(state):  # the final correction with the first Jacobian
            i, z_, r, scale = state
            return i, _axpy(-1.0, lu_solve(factors, r), z_), r, scale

        if max_iterations <= 1 + n_chord:  # the full iterations could never run: none compiled
            return _finish(*common((i, z, r, scale)))
        return _finish(*jax.lax.cond(jnp.any(active_of(i, r, scale)), fallback, common, (i, z, r, scale)))

    def _finish(i, z, r, scale):
        """z with per-member (iterations, relative residual, result), r the residual before the
        last correction."""
        rel = norm(r) / jnp.where(scale > 0, scale, 1.0)
        ok = finite(z) & finite(r)
        result = jnp.where(~ok, NONFINITE, jnp.where(rel <= rtol, SUCCESS, MAX_ITERATIONS))
        dtype = z[0].dtype  # custom_root's JVP rule mishandles integer auxiliary outputs
        return z, (i.astype(dtype), rel, result.astype(dtype))

    def tangent_solve(linear, y):
        return lu_solve(lu(columns(linear, y)), y)

    z, (i, rel, result) = jax.lax.custom_root(residual_only, z0, solve, tangent_solve, has_aux=True)
    stats = (i.astype(jnp.int32), rel, result.astype(jnp.int8))
    return z, jax.lax.stop_gradient(stats)
