"""Prototype: ``vi_jax.solvers.newton_root`` with a damped fallback (backtracking step halving
on ‖F‖∞), for measuring whether damping rescues the steps where plain Newton stops converging.
The engine is not modified: :func:`patched` swaps the solver that ``dep_step`` looks up while a
program is traced (jit caches are cleared on entry and exit)."""

import contextlib

import jax
import jax.numpy as jnp

from vi_jax.solvers import MAX_ITERATIONS, NONFINITE, SUCCESS, dense_solve, NewtonStats
from vi_jax.discrete import _dep

HALVINGS = 8  # trial step lengths 1, 1/2, …, 1/2⁷


def damped_newton_root(fn, z0, *, rtol, max_iterations, chord_iterations=2, explicit=None):
    """As the engine's ``newton_root`` (Newton, chord steps, check, full Newton fallback, final
    correction), except that each fallback iteration takes the longest step z − 2⁻ᵏΔz,
    k < ``HALVINGS``, that lowers ‖F‖∞ (the shortest if none does). ``explicit`` (the unknowns
    with explicit equations, which the engine solves first) is accepted and not used: this
    prototype runs Newton on every unknown, the same root."""
    del explicit

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

        def not_converged(r, scale):
            return jnp.max(jnp.abs(r)) > rtol * scale

        def cond(state):
            i, _, r, scale, _ = state
            return (i < max_iterations) & not_converged(r, scale) & jnp.all(jnp.isfinite(r))

        def body(state):
            i, z, r, _, jac = state
            dz = dense_solve(jac, r)
            lengths = 0.5 ** jnp.arange(HALVINGS, dtype=z.dtype)
            trials = z[None] - lengths[:, None] * dz[None]
            norms = jax.vmap(lambda u: jnp.max(jnp.abs(residual_only(u))))(trials)
            norms = jnp.where(jnp.isfinite(norms), norms, jnp.inf)
            better = norms < jnp.max(jnp.abs(r))
            k = jnp.where(jnp.any(better), jnp.argmax(better), HALVINGS - 1)
            z = trials[k]
            return (i + 1, z, *value_and_jac(z))

        r, scale, jac = value_and_jac(z_init)
        z = z_init
        n_chord = max(min(chord_iterations, max_iterations - 1), 0)
        for _ in range(1 + n_chord):
            z = z - dense_solve(jac, r)
            r, scale = fn(z)
        # The damped fallback restarts from the guess when the undamped start made things worse.
        r0, scale0, jac0 = value_and_jac(z_init)
        worse = ~(jnp.max(jnp.abs(r)) < jnp.max(jnp.abs(r0)))
        z = jnp.where(worse, z_init, z)
        r, scale, jac = jax.lax.cond(
            worse, lambda: (r0, scale0, jac0), lambda: value_and_jac(z)
        )
        state = (jnp.asarray(1 + n_chord, jnp.int32), z, r, scale, jac)
        state = jax.lax.cond(
            not_converged(r, scale), lambda s: jax.lax.while_loop(cond, body, s), lambda s: s, state
        )
        i, z, r, scale, jac = state
        z = z - dense_solve(jac, r)
        rel = jnp.max(jnp.abs(r)) / jnp.where(scale > 0, scale, 1.0)
        finite = jnp.all(jnp.isfinite(z)) & jnp.all(jnp.isfinite(r))
        result = jnp.where(~finite, NONFINITE, jnp.where(rel <= rtol, SUCCESS, MAX_ITERATIONS))
        return z, NewtonStats(i.astype(z.dtype), rel, result.astype(z.dtype))

    def tangent_solve(g, y):
        return dense_solve(jax.jacfwd(g)(jnp.zeros_like(y)), y)

    z, stats = jax.lax.custom_root(residual_only, z0, solve, tangent_solve, has_aux=True)
    stats = NewtonStats(stats.iterations.astype(jnp.int32), stats.residual, stats.result.astype(jnp.int8))
    return z, jax.lax.stop_gradient(stats)


@contextlib.contextmanager
def patched():
    """Inside the block, DEP steps traced from now on use :func:`damped_newton_root`."""
    original = _dep.newton_root
    jax.clear_caches()
    _dep.newton_root = damped_newton_root
    try:
        yield
    finally:
        _dep.newton_root = original
        jax.clear_caches()
