"""``simulate``: the DEP one-step map scanned over time, with per-step Newton statistics,
node diagnostics and an optional progress bar."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._diagnostics import kelvin_noether, kelvin_noether_scale
from ..solvers import RESULT_MESSAGES, SUCCESS
from .._system import AbstractSystem, State
from ..discrete import composition_coefficients, inverse_legendre, legendre_initial_state
from ..discrete._composition import ORDERS
from ..lie import difference_map
from .._accuracy import AccuracyWarning, warn_if_meaningless
from ._advance import advance_loop, advance_scan
from ._placement import placement
from .._precision import full_precision


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
    checkpoint: bool = True,
    device=None,
) -> Solution:
    """Integrate ``system`` from continuous initial data ``x0`` with the DEP scheme.

    ``tau``: "cayley" or "exp"; ``order``: 1 (the left-point rule: seed 000's eq. 71 for the
    vehicle), 2 (trapezoid, symmetric), 4 or 6 (symmetric compositions of order 2).
    The recursion starts from the continuous Legendre map (seed 000 spec §2). ``throw=True``
    raises :class:`NewtonFailure` (or an equinox runtime error under ``jit``) when a step fails;
    ``throw=False`` records it in ``Solution.result``. ``progress=True`` shows a progress bar
    (outside ``jit`` only). Jittable, vmappable and differentiable (implicit-function gradients).
    Reverse mode is checkpointed by default (memory grows with the number of saved nodes and
    blocks, not with the number of steps; the forward pass is recomputed once);
    ``checkpoint=False`` stores every step instead.

    Called on concrete inputs, one compiled program serves every ``n_steps`` and ``save_every``
    with the same saved-node capacity (a power of two): the step counts are traced integers.
    Under a transformation (``jit``, ``grad``, ``jvp``, ``vmap``) the loops have static lengths.
    A conservative run whose energy error says it is meaningless warns (:class:`AccuracyWarning`).
    ``device``: where a concrete run executes — None (the default device; on an accelerator a
    one-time :class:`PerformanceWarning`: single trajectories are latency-bound there), "cpu" or
    a ``jax.Device``.
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
    options = dict(tau=tau, rule=rule, gammas=gammas, rtol=rtol, max_iter=max_newton_iterations)
    with full_precision():
        if not val.is_concrete((system, x0, h)):
            sol = _simulate_scan(system, x0, h, n_saved, save_every=save_every, checkpoint=bool(checkpoint), **options)
        elif progress:
            with placement(device):
                sol = _simulate_with_progress(system, x0, h, n_saved, save_every, **options)
        else:
            with placement(device):
                count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731  (traced: no recompilation)
                sol = _simulate_loop(system, x0, h, count(n_saved), count(save_every), capacity=_capacity(n_saved), **options)
                sol = _rows(sol, n_saved + 1)
    if throw:
        sol = _check_failure(sol, save_every)
    warn_if_meaningless(sol.energy, "simulate")
    return sol


def _capacity(n_saved: int) -> int:
    """Saved-node buffer size: the next power of two (one program per capacity)."""
    return 1 << max(n_saved - 1, 0).bit_length()


def _rows(sol, n):
    """The first ``n`` rows, sliced on the host: an eager device slice would compile a small
    program for every new ``n``."""
    return jax.tree.map(lambda x: jax.device_put(np.asarray(x)[:n], next(iter(x.devices()))), sol)


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


def _initial(system, x0):
    return legendre_initial_state(system, x0.g, x0.xi, x0.q, x0.qdot)


@eqx.filter_jit
def _simulate_scan(system, x0, h, n_saved, *, tau, rule, gammas, save_every, rtol, max_iter, checkpoint):
    state0 = _initial(system, x0)
    _, saved, stats = advance_scan(system, tau, rule, gammas, h, state0, n_saved, save_every, rtol, max_iter, checkpoint)
    return _assemble(system, state0, saved, stats, h, save_every, rtol, max_iter)


@eqx.filter_jit
def _simulate_loop(system, x0, h, n_saved, save_every, *, capacity, tau, rule, gammas, rtol, max_iter):
    state0 = _initial(system, x0)
    _, saved, stats = advance_loop(system, tau, rule, gammas, h, state0, n_saved, save_every, capacity, rtol, max_iter)
    return _assemble(system, state0, saved, stats, h, save_every, rtol, max_iter)


_initial_jit = eqx.filter_jit(_initial)
_advance_loop_jit = eqx.filter_jit(advance_loop)
_assemble_jit = eqx.filter_jit(_assemble)


def _simulate_with_progress(system, x0, h, n_saved, save_every, *, tau, rule, gammas, rtol, max_iter):
    """The same computation in ≤ 100 pieces of one compiled loop, with a tqdm bar between them."""
    from tqdm.auto import tqdm

    state0 = state = _initial_jit(system, x0)
    n_chunks = min(n_saved, 100)
    sizes = [n_saved // n_chunks + (i < n_saved % n_chunks) for i in range(n_chunks)]
    capacity = _capacity(sizes[0])
    count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731
    saved_parts, stats_parts = [], []
    with tqdm(total=n_saved * save_every, unit="step", desc="simulate") as bar:
        for size in sizes:
            state, saved, stats = _advance_loop_jit(
                system, tau, rule, gammas, h, state, count(size), count(save_every), capacity, rtol, max_iter
            )
            saved_parts.append(jax.tree.map(lambda x: x[:size], saved))
            stats_parts.append(jax.tree.map(lambda x: x[:size], stats))
            bar.update(size * save_every)
    # Pad to the power-of-two capacity so the node diagnostics compile once per capacity too.
    total = _capacity(n_saved)
    cat = lambda *xs: jnp.concatenate(xs + (jnp.broadcast_to(xs[-1][-1:], (total - n_saved,) + xs[-1].shape[1:]),))  # noqa: E731
    saved, stats = jax.tree.map(cat, *saved_parts), jax.tree.map(cat, *stats_parts)
    return _rows(_assemble_jit(system, state0, saved, stats, h, count(save_every), rtol, max_iter), n_saved + 1)


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
