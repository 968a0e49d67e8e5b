"""Newton's method for the small dense systems of one implicit step, with implicit-function
gradients (``jax.lax.custom_root``): reverse mode never unrolls the iterations.

The linear solves are unrolled Gaussian elimination without pivoting: for the 3–12
unknowns of a step this is far cheaper inside ``lax.scan`` on CPU than a LAPACK call
(``benchmarks/step_cost.py`` measures the whole step). Newton factors its Jacobian once
(:func:`lu_factor`) and reuses the factors for the chord steps and the final correction,
also across the fallback's conditional, where XLA cannot share an elimination.
"""

import contextlib

import equinox as eqx
import jax
import jax.numpy as jnp

from ..lie._small import traced_with_fused_products

# Result codes recorded per step (0 = success).
SUCCESS = 0
MAX_ITERATIONS = 1
NONFINITE = 2
SINGULAR_DIFFERENCE_MAP = 3
NOT_SEPARABLE = 4  # scheme="splitting" on a traced scene that is not separable (throw=False)

CHORD_ITERATIONS = 2

RESULT_MESSAGES = {
    MAX_ITERATIONS: "Newton did not converge within max_newton_iterations",
    NONFINITE: "Newton produced a non-finite value",
    SINGULAR_DIFFERENCE_MAP: "h|ξ| reached the singular set of τ = exp (a rotation angle ≥ π per step)",
    NOT_SEPARABLE: "the scene is not separable, which scheme='splitting' needs (a traced scene's run-time check)",
}


def dense_solve(A, b):
    """Solve A x = b for a small square A by unrolled Gaussian elimination without pivoting.

    The Newton matrices of a step are h-perturbations of the Hessian of a regular Lagrangian in
    its velocities (positive definite kinetic energy), for which elimination without pivoting
    is stable; a breakdown shows up as a non-finite or non-converged step, never silently.
    Pivoting's gathers double the cost of a step on CPU (benchmarks/step_cost.py).
    """
    n = A.shape[0]
    rows = []
    for k in range(n):  # forward elimination, one row at a time
        row, rhs = A[k], b[k]
        for j, (prev, prev_rhs) in enumerate(rows):
            factor = row[j] / prev[j]
            row, rhs = row - factor * prev, rhs - factor * prev_rhs
        rows.append((row, rhs))
    x = [None] * n
    for k in reversed(range(n)):
        row, rhs = rows[k]
        acc = rhs
        for j in range(k + 1, n):
            acc = acc - row[j] * x[j]
        x[k] = acc / row[k]
    return jnp.stack(x)


class LUFactors(eqx.Module):
    """Factors of a small square A = LU without pivoting (:func:`lu_factor`)."""

    upper: jax.Array  # U on and above the diagonal (below it: round-off, never read)
    lower: jax.Array  # L's multipliers below the diagonal (unit diagonal implied), zero elsewhere
    inverse_diagonal: jax.Array  # 1 / U_jj


def lu_factor(A) -> LUFactors:
    """LU factors of a small square ``A`` without pivoting (see :func:`dense_solve` for why no
    pivoting), eliminating one column of the whole matrix at a time: a step's Jacobian is
    factored in n fused updates (``python benchmarks/step_cost.py``, its row "Jacobian
    eliminated at every solve")."""
    n = A.shape[0]
    below = jnp.arange(n)[:, None] > jnp.arange(n)[None, :]
    U, multipliers, inverse = A, [], []
    for j in range(n):
        d = 1 / U[j, j]
        m = jnp.where(below[:, j], U[:, j] * d, 0)
        U = U - m[:, None] * U[j][None, :]
        multipliers.append(m)
        inverse.append(d)
    return LUFactors(U, jnp.stack(multipliers, axis=1), jnp.stack(inverse))


def lu_solve(factors: LUFactors, b):
    """x with A x = b from :func:`lu_factor`'s factors of A (``b``: a vector or the columns of a
    matrix), by unrolled substitution: multiply-and-subtract only, one fused kernel."""
    n = b.shape[0]
    U, L, inverse = factors.upper, factors.lower, factors.inverse_diagonal
    y = []
    for i in range(n):
        acc = b[i]
        for j in range(i):
            acc = acc - L[i, j] * y[j]
        y.append(acc)
    x = [None] * n
    for i in reversed(range(n)):
        acc = y[i]
        for c in range(i + 1, n):
            acc = acc - U[i, c] * x[c]
        x[i] = acc * inverse[i]
    return jnp.stack(x)


def traced_once(fn, z):
    """``fn`` traced at ``z``'s shape once; the returned function replays its jaxpr, with its
    small products as multiply-and-sum (:func:`~vi_jax.lie._small.fused_products`). Newton's
    Jacobian, chord steps, full iterations and ``custom_root`` call it six times: replaying
    skips the model's Python code (the vehicle's first ``vj.simulate`` call 2.76 → 2.31 s,
    most of it tracing and lowering; README, "Compiling"). The replay is a ``jax.jit``: its
    jaxpr is built once and so are its JVP and batched jaxprs (JAX caches them per jaxpr), where
    each call would otherwise replay the residual under forward mode and ``vmap`` anew; XLA
    inlines the calls."""
    return jax.jit(traced_with_fused_products(fn, z))


_ROLLED = False


@contextlib.contextmanager
def rolled_iterations():
    """While active, :func:`newton_root` traces the residual and its Jacobian once each: one
    ``while`` loop over the evaluations, each of the residual and, where Newton needs new factors
    (the first point, the full iterations), of the Jacobian's factors in a conditional whose
    other branch keeps them. Unrolled, the first Newton step and the chord steps hold the
    residual three times and the full iterations the Jacobian a second time. The same iterates,
    each checked: the loop stops at the first converged one, where the unrolled steps check once,
    after the chord steps (the vehicle converges after the Newton step in 97% of its steps, the
    heavy top after one chord step). Against checking once, minima of 15–31 alternate timings of
    a concrete ``vj.simulate`` call (50,000 steps, its node diagnostics included) in a throwaway
    A/B, default XLA and the loop option: the vehicle 0.86–0.87× at order 1, 0.92–0.94× at order 2,
    the heavy top at order 2 0.85–0.92×, the rigid body at order 1 0.68× (loop option only); two
    first runs of 15 timings read 1.35× (vehicle order 2) and 1.14× (heavy top, default XLA) by
    their minima, 0.95× and 0.93× by their medians, and their reruns of 31 the figures above. The first
    point's residual is evaluated twice (alone and with the Jacobian):
    a conditional choosing between the two evaluations made the vehicle's concrete steps 1.33×
    the unrolled ones, against 1.10× so (minima of 11 alternate timings, in a throwaway A/B
    when this was written). For loops that are one kernel (an
    :func:`~vi_jax._saved_nodes.in_one_kernel` region): the vehicle's concrete ``vj.simulate``
    program (order 1) holds 2,398 jaxpr equations instead of 3,726, and order 2's 2,934 instead
    of 5,490 (one kernel instead of XLA:CPU's default loop plan). Timings:
    :func:`vi_jax.engine._advance.advance_loop`."""
    global _ROLLED
    previous, _ROLLED = _ROLLED, True
    try:
        yield
    finally:
        _ROLLED = previous


_IMPLICIT_GRADIENTS = True


@contextlib.contextmanager
def without_implicit_gradients():
    """While active, the Newton solves traced below (:func:`newton_root`, the engine's
    ``newton_members``) run their iterations without ``jax.lax.custom_root``'s implicit-function
    rule. Tracing that rule traces the tangent solve too (the residual linearised, its Jacobian
    factored) although a program that nothing differentiates never runs it: for a concrete
    call's programs only (:func:`vi_jax.engine._compile_options.cpu_options_jit`), whose inputs
    are concrete. The same values; the vehicle's first ``vj.simulate`` call 2.30–2.39 →
    2.00–2.01 s, all of it tracing (``python benchmarks/compile_time.py``: README, "Compiling")."""
    global _IMPLICIT_GRADIENTS
    previous, _IMPLICIT_GRADIENTS = _IMPLICIT_GRADIENTS, False
    try:
        yield
    finally:
        _IMPLICIT_GRADIENTS = previous


def implicit_root(f, z0, solve, tangent_solve):
    """``jax.lax.custom_root(f, z0, solve, tangent_solve, has_aux=True)``; ``solve(f, z0)``
    under :func:`without_implicit_gradients`."""
    if not _IMPLICIT_GRADIENTS:
        return solve(f, z0)
    return jax.lax.custom_root(f, z0, solve, tangent_solve, has_aux=True)


def _is_range(idx):
    return list(idx) == list(range(idx[0], idx[-1] + 1))


def _take(x, idx):
    """The entries ``idx`` (a list) of the vector ``x`` (a slice where they are contiguous)."""
    if _is_range(idx):
        return x[idx[0] : idx[-1] + 1]
    return jnp.stack([x[i] for i in idx])


def _put(x, idx, values):
    """``x`` with its entries ``idx`` (a list) replaced by ``values``."""
    if _is_range(idx):
        return jnp.concatenate([x[: idx[0]], values, x[idx[-1] + 1 :]])
    parts = list(x)
    for i, v in zip(idx, values):
        parts[i] = v
    return jnp.stack(parts)


class NewtonStats(eqx.Module):
    iterations: jax.Array
    residual: jax.Array  # ‖F(z) − target‖∞ / scale at the returned z
    result: jax.Array


def newton_root(fn, z0, *, rtol, max_iterations, chord_iterations=CHORD_ITERATIONS, explicit=None):
    """Root of ``fn(z) -> (residual, scale)`` near ``z0`` (a good guess: the previous step).

    One Newton step, then ``chord_iterations`` steps that reuse its Jacobian (residual-only
    evaluations), then a convergence check: ‖residual‖∞ ≤ rtol·scale, ``scale`` being the size of
    the terms that cancel in the residual. If it fails, full Newton iterations continue (up to
    ``max_iterations`` in all); rolled (:func:`rolled_iterations`), every iterate is checked and
    the first converged one stops them. A final correction with the Jacobian at hand follows the check:
    stopping at the tolerance itself would leave an O(rtol) bias per step that accumulates in the
    conserved quantities. A ``while_loop`` iteration inside ``lax.scan`` costs more on CPU than
    the arithmetic of a small step, so the common path has none (benchmarks/step_cost.py), but
    where the loops are one kernel (:func:`rolled_iterations`).
    With ``max_iterations`` ≤ 1 + ``chord_iterations`` the program holds no full iterations.

    ``explicit``: (rows, columns) of unknowns with explicit equations — rows of the residual
    affine in those unknowns alone, with coefficients that do not depend on z (seed 000 eq. 74's
    ν; found by :func:`vi_jax.engine._explicit_unknowns.explicit_unknowns`). They are solved
    exactly first and Newton runs on the other unknowns with them fixed: a smaller Jacobian to
    evaluate and factor (``python benchmarks/step_cost.py``, its row "Newton on every unknown").

    Returns the root and :class:`NewtonStats` (``residual``: relative, before the final
    correction); gradients flow through the implicit-function theorem, of the whole system.
    """

    fn = traced_once(fn, z0)

    def residual_only(z):
        return fn(z)[0]

    def solve(f, z_init):
        del f
        if explicit is None:
            return iterate(fn, z_init)
        rows, cols = explicit
        other_rows = [i for i in range(z_init.shape[0]) if i not in rows]
        others = [j for j in range(z_init.shape[0]) if j not in cols]

        def explicit_rows(v):
            r = _take(fn(_put(z_init, cols, v))[0], rows)
            return r, r

        v = _take(z_init, cols)
        coefficients, r = jax.jacfwd(explicit_rows, has_aux=True)(v)
        z = _put(z_init, cols, v - lu_solve(lu_factor(coefficients), r))

        def fn_others(u):
            r, scale = fn(_put(z, others, u))
            return _take(r, other_rows), scale

        u, stats = iterate(fn_others, _take(z, others))
        z = _put(z, others, u)
        result = jnp.where(jnp.all(jnp.isfinite(z)), stats.result, NONFINITE)
        return z, NewtonStats(stats.iterations, stats.residual, result.astype(z.dtype))

    def iterate(fn, z_init):
        def with_aux(u):
            r, scale = fn(u)
            return r, (r, scale)

        def value_and_factors(z):
            jac, (r, scale) = jax.jacfwd(with_aux, has_aux=True)(z)
            return r, scale, lu_factor(jac)

        def not_converged(r, scale):
            return jnp.max(jnp.abs(r)) > rtol * scale

        def cond(state):
            i, _, r, scale, _ = state
            return (i < max_iterations) & not_converged(r, scale) & jnp.all(jnp.isfinite(r))

        def body(state):
            i, z, r, _, factors = state
            z = z - lu_solve(factors, r)
            return (i + 1, z, *value_and_factors(z))

        def rolled(z_init, n_chord):
            """:func:`rolled_iterations`' loop over the evaluations; the first (k = 0) follows a
            zero update of ``z_init`` (r = 0, the identity's factors)."""

            def going(state):
                k, *rest = state  # k evaluations so far: k − 1 iterations
                return (k < 2) | cond((k - 1, *rest))

            def evaluation(state):
                k, z, r, _, factors = state
                z = z - lu_solve(factors, r)
                r, scale = fn(z)
                refresh = lambda z, _: value_and_factors(z)[2]  # noqa: E731
                factors = jax.lax.cond((k == 0) | (k >= 2 + n_chord), refresh, lambda _, kept: kept, z, factors)
                return (k + 1, z, r, scale, factors)

            n, dtype = z_init.shape[0], z_init.dtype
            identity = lu_factor(jnp.eye(n, dtype=dtype))
            start = (jnp.asarray(0, jnp.int32), z_init, jnp.zeros_like(z_init), jnp.ones((), dtype), identity)
            k, z, r, scale, factors = jax.lax.while_loop(going, evaluation, start)
            return k - 1, z, r, scale, factors

        n_chord = max(min(chord_iterations, max_iterations - 1), 0)
        if _ROLLED:
            return finish(*rolled(z_init, n_chord))
        r, scale, factors = value_and_factors(z_init)
        z = z_init
        for _ in range(1 + n_chord):
            z = z - lu_solve(factors, r)
            r, scale = fn(z)
        state = (jnp.asarray(1 + n_chord, jnp.int32), z, r, scale, factors)
        if max_iterations > 1 + n_chord:  # else the full iterations could never run: none compiled
            state = jax.lax.cond(
                not_converged(r, scale), lambda s: jax.lax.while_loop(cond, body, s), lambda s: s, state
            )
        return finish(*state)

    def finish(i, z, r, scale, factors):
        """The final correction and the statistics after ``i`` iterations."""
        z = z - lu_solve(factors, r)
        rel = jnp.max(jnp.abs(r)) / jnp.where(scale > 0, scale, 1.0)
        finite = jnp.all(jnp.isfinite(z)) & jnp.all(jnp.isfinite(r))
        result = jnp.where(~finite, NONFINITE, jnp.where(rel <= rtol, SUCCESS, MAX_ITERATIONS))
        # custom_root's JVP rule mishandles integer auxiliary outputs: carry them as floats.
        return z, NewtonStats(i.astype(z.dtype), rel, result.astype(z.dtype))

    def tangent_solve(g, y):
        return lu_solve(lu_factor(jax.jacfwd(g)(jnp.zeros_like(y))), y)

    z, stats = implicit_root(residual_only, z0, solve, tangent_solve)
    stats = NewtonStats(stats.iterations.astype(jnp.int32), stats.residual, stats.result.astype(jnp.int8))
    return z, jax.lax.stop_gradient(stats)
