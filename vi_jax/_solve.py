"""Newton's method for the small dense systems of one implicit step, with implicit-function
gradients (``jax.lax.custom_root``): reverse mode never unrolls the iterations.

The linear solves are unrolled Gaussian elimination with partial pivoting: for the 3–12
unknowns of a step this is far cheaper inside ``lax.scan`` on CPU than a LAPACK call
(``benchmarks/step_cost.py`` measures the whole step).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

# Result codes recorded per step (0 = success).
SUCCESS = 0
MAX_ITERATIONS = 1
NONFINITE = 2
SINGULAR_DIFFERENCE_MAP = 3

RESULT_MESSAGES = {
    MAX_ITERATIONS: "Newton did not converge within max_newton_iterations",
    NONFINITE: "Newton produced a non-finite value",
    SINGULAR_DIFFERENCE_MAP: "h|ξ| reached the singular set of τ = exp (a rotation angle ≥ π per step)",
}


def dense_solve(A, b):
    """Solve A x = b for a small square A by unrolled Gaussian elimination with partial pivoting."""
    n = A.shape[0]
    if n == 1:
        return b / A[0, 0]
    Ab = jnp.concatenate([A, b[:, None]], axis=1)
    rows = jnp.arange(n)
    for k in range(n):
        pivot = k + jnp.argmax(jnp.abs(Ab[k:, k]))
        perm = jnp.where(rows == k, pivot, jnp.where(rows == pivot, k, rows))
        Ab = Ab[perm]
        factors = jnp.where(rows > k, Ab[:, k] / Ab[k, k], 0.0)
        Ab = Ab - factors[:, None] * Ab[k][None, :]
    x = jnp.zeros(n, Ab.dtype)
    for k in reversed(range(n)):
        x = x.at[k].set((Ab[k, n] - Ab[k, k + 1 : n] @ x[k + 1 :]) / Ab[k, k])
    return x


class NewtonStats(eqx.Module):
    iterations: jax.Array
    residual: jax.Array  # ‖F(z) − target‖∞ / scale at the returned z
    result: jax.Array


def newton_root(fn, z0, *, rtol, max_iterations):
    """Root of ``fn(z) -> (residual, scale)`` near ``z0``.

    Iterates until ‖residual‖∞ ≤ rtol·scale (``scale`` = size of the terms that cancel in the
    residual), then applies one more Newton correction with the Jacobian already at hand (no
    extra evaluation): stopping at the tolerance itself would leave an O(rtol) bias per step
    that accumulates in the conserved quantities. Returns the root and :class:`NewtonStats`
    (``residual``: relative, before the final correction); gradients flow through the
    implicit-function theorem.
    """

    def residual_only(z):
        return fn(z)[0]

    def solve(f, z_init):
        del f

        def with_aux(u):
            r, scale = fn(u)
            return r, (r, scale)

        def value_and_jac(z):
            jac, (r, scale) = jax.jacfwd(with_aux, has_aux=True)(z)
            return r, scale, jac

        def cond(state):
            i, _, r, scale, _ = state
            return (i < max_iterations) & (jnp.max(jnp.abs(r)) > rtol * scale) & jnp.all(jnp.isfinite(r))

        def body(state):
            i, z, r, _, jac = state
            z = z - dense_solve(jac, r)
            return (i + 1, z, *value_and_jac(z))

        state = (jnp.zeros((), jnp.int32), z_init, *value_and_jac(z_init))
        i, z, r, scale, jac = jax.lax.while_loop(cond, body, state)
        z = z - dense_solve(jac, r)
        rel = jnp.max(jnp.abs(r)) / jnp.where(scale > 0, scale, 1.0)
        finite = jnp.all(jnp.isfinite(z)) & jnp.all(jnp.isfinite(r))
        result = jnp.where(~finite, NONFINITE, jnp.where(rel <= rtol, SUCCESS, MAX_ITERATIONS))
        return z, NewtonStats(i, rel, result.astype(jnp.int8))

    def tangent_solve(g, y):
        return dense_solve(jax.jacfwd(g)(jnp.zeros_like(y)), y)

    return jax.lax.custom_root(residual_only, z0, solve, tangent_solve, has_aux=True)
