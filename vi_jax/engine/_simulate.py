"""``simulate``: the DEP one-step map scanned over time, with per-step Newton statistics,
node diagnostics and an optional progress bar."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._diagnostics import kelvin_noether, kelvin_noether_scale
from ..solvers import RESULT_MESSAGES, SUCCESS
from .._system import AbstractSystem, State
from ..discrete import composition_coefficients, dep_step, inverse_legendre, legendre_initial_state
from ..discrete._composition import ORDERS
from ..lie import difference_map


class NewtonFailure(RuntimeError):
    """A DEP step whose implicit equations were not solved (``throw=True``)."""


class Solution(eqx.Module):
    """Trajectory at the saved nodes (leading axis = time, n_saved + 1 rows).

    ``g``/``R``: configuration; ``xi``/``omega``: body velocity and ``nu``: body velocity of the
    additional dynamics, both from the continuous inverse Legendre map at the nodes; ``M``, ``P``:
    discrete body momenta; ``energy``; ``kelvin_noether`` (a scalar per node when the isotropy
    algebra is one-dimensional, else one column per basis element) and ``kelvin_noether_scale``
    (|M| + |P||n|, the size of the terms that cancel in it). Newton statistics per saved node
    (the worst over the steps since the previous saved node; row 0 is the initial data):
    ``newton_iterations``, ``newton_residual`` (relative), ``result`` (0 = success).
    """

    t: jax.Array
    g: jax.Array
    xi: jax.Array
    q: jax.Array | None
    nu: jax.Array | None
    M: jax.Array
    P: jax.Array | None
    energy: jax.Array
    kelvin_noether: jax.Array
    kelvin_noether_scale: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    result: jax.Array

    @property
    def R(self):
        return self.g

    @property
    def omega(self):
        return self.xi

    @property
    def succeeded(self):
        return jnp.all(self.result == SUCCESS)


def _default_rtol(dtype):
    return float(64 * jnp.finfo(dtype).eps)


def _validate(system, x0, h, n_steps, tau, order, save_every):
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a vi_jax system (AbstractSystem), got {type(system).__name__}")
    if not isinstance(x0, State):
        raise ValueError(f"x0: expected a vi_jax.State (e.g. model.initial_state()), got {type(x0).__name__}")
    G = system.group
    d, r = G.matrix_size, G.dim
    g0 = val.as_array("x0.g", x0.g, (d, d))
    xi0 = val.as_array("x0.xi", x0.xi, (r,))
    val.check_finite("x0.g", g0)
    val.check_finite("x0.xi", xi0)
    val.check_on_group("x0.g", G, g0)
    if system.has_additional:
        if x0.q is None or x0.qdot is None:
            raise ValueError("x0: this system has additional dynamics; expected x0.q and x0.qdot, got None")
        m = jnp.shape(x0.q)[-1] if jnp.ndim(x0.q) else None
        val.as_array("x0.q", x0.q, (m,))
        val.as_array("x0.qdot", x0.qdot, (m,))
        val.check_finite("x0.q", x0.q)
        val.check_finite("x0.qdot", x0.qdot)
    elif x0.q is not None or x0.qdot is not None:
        raise ValueError("x0: this system has no additional dynamics; expected x0.q = x0.qdot = None")
    val.check_finite("system parameters", val.numeric_leaves(system))
    h = val.check_positive_scalar("h", h)
    n_steps, save_every = val.check_steps(n_steps, save_every)
    val.check_choice("order", order, ORDERS)
    return h, n_steps, save_every, difference_map(tau)


SAVE_BLOCK = 128  # saved nodes per inner scan (see _advance)


def _advance(system, tau, rule, gammas, h, state, length, save_every, rtol, max_iter, checkpoint=False):
    """``length`` saved nodes of ``save_every`` steps each; returns (final state, saved states, stats).

    Nodes are saved through a two-level scan (blocks of ``SAVE_BLOCK`` nodes): writing every
    step's state straight into one long output buffer costs XLA:CPU more than the step itself
    (benchmarks/step_cost.py). With ``checkpoint``, reverse mode stores only the state at block
    boundaries (and at saved nodes) and recomputes the steps inside a block; the steps between
    two saved nodes run as √save_every rematerialised blocks, so memory grows like
    n/(SAVE_BLOCK·save_every) + SAVE_BLOCK + √save_every states (benchmarks/gradients.py).
    """

    def sub_step(state, gamma):
        new, stats = dep_step(system, tau, rule, gamma * h, state, rtol=rtol, max_iterations=max_iter)
        # After a failed step the state is NaN (and every later step reports NONFINITE): a
        # partial Solution never continues from a state that did not solve the equations.
        failed = stats.result != SUCCESS
        return jax.tree.map(lambda x: jnp.where(failed, jnp.nan, x), new), stats

    def one_step(state, _):
        if len(gammas) == 1:
            return sub_step(state, gammas[0])
        # A rolled loop over the composition's sub-steps: one copy of the step to compile.
        state, stats = jax.lax.scan(sub_step, state, jnp.asarray(gammas, h.dtype))
        return state, jax.tree.map(lambda x: jnp.max(x, axis=0), stats)

    def steps(state, n):
        state, stats = jax.lax.scan(one_step, state, None, length=n)
        return state, jax.tree.map(lambda x: jnp.max(x, axis=0), stats)

    def node_steps(state):
        if not checkpoint or save_every <= SAVE_BLOCK:
            return steps(state, save_every)
        # √save_every rematerialised blocks: reverse mode stores O(√save_every) step residuals.
        inner = math.isqrt(save_every)
        outer, rest = divmod(save_every, inner)
        state, stats = jax.lax.scan(jax.checkpoint(lambda s, _: steps(s, inner)), state, None, length=outer)
        stats = jax.tree.map(lambda x: jnp.max(x, axis=0), stats)
        if rest:
            state, more = steps(state, rest)
            stats = jax.tree.map(jnp.maximum, stats, more)
        return state, stats

    def node(state, _):
        state, stats = one_step(state, None) if save_every == 1 else node_steps(state)
        return state, (state, stats)

    if checkpoint:
        node = jax.checkpoint(node)

    def block(state, _):
        return jax.lax.scan(node, state, None, length=SAVE_BLOCK)

    if checkpoint:
        block = jax.checkpoint(block)

    n_blocks, rest = divmod(length, SAVE_BLOCK)
    pieces = []
    if n_blocks:
        state, out = jax.lax.scan(block, state, None, length=n_blocks)
        pieces.append(jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), out))
    if rest:
        state, out = jax.lax.scan(node, state, None, length=rest)
        pieces.append(out)
    saved, stats = jax.tree.map(lambda *xs: jnp.concatenate(xs), *pieces) if len(pieces) > 1 else pieces[0]
    return state, saved, stats


_advance_jit = eqx.filter_jit(_advance)


def _node_diagnostics(system, states, rtol, max_iter):
    inv = jax.vmap(
        lambda g, q, M, P, z: inverse_legendre(system, g, q, M, P, z, rtol=rtol, max_iterations=max_iter)
    )
    xi, nu = inv(states.g, states.q, states.M, states.P, states.z)
    n = jax.vmap(system.body_configuration)(states.g, states.q)
    a = jax.vmap(system.body_advected)(states.g)
    energy = jax.vmap(system.energy)(xi, n, nu, a)
    kn = jax.vmap(lambda *s: kelvin_noether(system, *s))(states.g, states.q, states.M, states.P)
    if kn.shape[-1] == 1:
        kn = kn[..., 0]
    kn_scale = jax.vmap(lambda *s: kelvin_noether_scale(system, *s))(states.g, states.q, states.M, states.P)
    return xi, nu, energy, kn, kn_scale


def simulate(
    system,
    x0: State,
    h,
    n_steps: int,
    *,
    tau="cayley",
    order: int = 1,
    save_every: int = 1,
    throw: bool = True,
    rtol=None,
    max_newton_iterations: int = 20,
    progress: bool = False,
    checkpoint: bool = False,
) -> Solution:
    """Integrate ``system`` from continuous initial data ``x0`` with the DEP scheme.

    ``tau``: "cayley" or "exp"; ``order``: 1 (the left-point rule: seed 000's eq. 71 for the
    vehicle), 2 (trapezoid, symmetric), 4 or 6 (symmetric compositions of order 2).
    The recursion starts from the continuous Legendre map (seed 000 spec §2). ``throw=True``
    raises :class:`NewtonFailure` (or an equinox runtime error under ``jit``) when a step fails;
    ``throw=False`` records it in ``Solution.result``. ``progress=True`` shows a progress bar
    (outside ``jit`` only). Jittable, vmappable and differentiable (implicit-function gradients);
    ``checkpoint=True`` makes reverse-mode memory grow with the number of saved nodes and blocks
    rather than with the number of steps, at the price of recomputing the forward pass.
    """
    h, n_steps, save_every, tau = _validate(system, x0, h, n_steps, tau, order, save_every)
    rule, gammas = composition_coefficients(order)
    dtype = jnp.result_type(x0.g, x0.xi, h)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    h = jnp.asarray(h, dtype)
    rtol = _default_rtol(dtype) if rtol is None else float(rtol)
    cast = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    x0 = State(cast(x0.g), cast(x0.xi), cast(x0.q), cast(x0.qdot))
    n_saved = n_steps // save_every
    options = dict(
        tau=tau, rule=rule, gammas=gammas, save_every=save_every, rtol=rtol,
        max_iter=max_newton_iterations, checkpoint=bool(checkpoint),
    )
    if progress and val.is_concrete((system, x0, h)):
        sol = _simulate_with_progress(system, x0, h, n_saved, **options)
    else:
        sol = _simulate_jit(system, x0, h, n_saved, **options)
    return _check_failure(sol, save_every) if throw else sol


def _assemble(system, state0, saved, stats, h, save_every, rtol, max_iter):
    states = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), state0, saved)
    xi, nu, energy, kn, kn_scale = _node_diagnostics(system, states, rtol, max_iter)
    first = lambda x, v: jnp.concatenate([jnp.full((1,), v, x.dtype), x])  # noqa: E731
    return Solution(
        t=h * save_every * jnp.arange(states.M.shape[0], dtype=h.dtype),
        g=states.g,
        xi=xi,
        q=states.q,
        nu=nu,
        M=states.M,
        P=states.P,
        energy=energy,
        kelvin_noether=kn,
        kelvin_noether_scale=kn_scale,
        newton_iterations=first(stats.iterations, 0),
        newton_residual=first(stats.residual, 0),
        result=first(stats.result, SUCCESS),
    )


@eqx.filter_jit
def _simulate_jit(system, x0, h, n_saved, *, tau, rule, gammas, save_every, rtol, max_iter, checkpoint):
    state0 = legendre_initial_state(system, x0.g, x0.xi, x0.q, x0.qdot)
    _, saved, stats = _advance(
        system, tau, rule, gammas, h, state0, n_saved, save_every, rtol, max_iter, checkpoint
    )
    return _assemble(system, state0, saved, stats, h, save_every, rtol, max_iter)


def _simulate_with_progress(system, x0, h, n_saved, *, tau, rule, gammas, save_every, rtol, max_iter, checkpoint):
    """The same computation in ≤ 100 jitted pieces, with a tqdm bar between them."""
    from tqdm.auto import tqdm

    state = legendre_initial_state(system, x0.g, x0.xi, x0.q, x0.qdot)
    state0 = state
    n_chunks = min(n_saved, 100)
    sizes = [n_saved // n_chunks + (i < n_saved % n_chunks) for i in range(n_chunks)]
    saved_parts, stats_parts = [], []
    with tqdm(total=n_saved * save_every, unit="step", desc="simulate") as bar:
        for size in sizes:
            state, saved, stats = _advance_jit(
                system, tau, rule, gammas, h, state, size, save_every, rtol, max_iter, checkpoint
            )
            saved_parts.append(saved)
            stats_parts.append(stats)
            bar.update(size * save_every)
    cat = lambda *xs: jnp.concatenate(xs)  # noqa: E731
    saved, stats = jax.tree.map(cat, *saved_parts), jax.tree.map(cat, *stats_parts)
    return eqx.filter_jit(_assemble)(system, state0, saved, stats, h, save_every, rtol, max_iter)


def _check_failure(sol: Solution, save_every: int) -> Solution:
    failed = sol.result != SUCCESS
    if val.is_concrete(failed):
        if bool(jnp.any(failed)):
            k = int(np.argmax(np.asarray(failed)))
            code = int(sol.result[k])
            steps = f"step {k - 1}" if save_every == 1 else f"steps {(k - 1) * save_every}..{k * save_every - 1}"
            raise NewtonFailure(
                f"DEP step failed at {steps} (t ≈ {float(sol.t[k]):.6g}): {RESULT_MESSAGES.get(code, code)}; "
                f"relative residual {float(sol.newton_residual[k]):.3g} after "
                f"{int(sol.newton_iterations[k])} iterations. Reduce h, raise max_newton_iterations, "
                "or pass throw=False to inspect the partial Solution."
            )
        return sol
    return eqx.error_if(sol, jnp.any(failed), "DEP step failed (Newton did not converge or τ singular); pass throw=False to inspect Solution.result")
