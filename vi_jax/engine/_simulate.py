"""``simulate``: the DEP one-step map scanned over time, with per-step Newton statistics,
node diagnostics and an optional progress bar."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from ..solvers import RESULT_MESSAGES, SUCCESS
from .._system import State
from ..discrete import composition_coefficients, legendre_initial_state
from ..discrete._composition import ORDERS
from ..discrete._splitting import ORDERS as SPLITTING_ORDERS
from ..lie import difference_map
from .._accuracy import warn_if_meaningless
from ._advance import advance_loop, advance_scan, initial_first, traced_composition
from ._compile_options import single_trajectory_jit
from ._placement import placement
from .._precision import full_precision
from ..lie._small import keeping_dots
from .._saved_nodes import first_rows, saved_capacity
from ._node_velocities import node_velocities
from ._overlapped_compiles import run_chained
from ._simulate_splitting import simulate_splitting
from ._solution import Solution, node_invariants, validate_inputs


class NewtonFailure(RuntimeError):
    """A DEP step whose implicit equations were not solved (``throw=True``)."""


def _default_rtol(dtype):
    return float(64 * jnp.finfo(dtype).eps)


def _validate(system, x0, h, n_steps, tau, order, save_every, values=True):
    h, n_steps, save_every = validate_inputs(system, x0, h, n_steps, save_every, values)
    val.check_choice("order", order, ORDERS)
    return h, n_steps, save_every, difference_map(tau)


def _node_diagnostics(system, states, rtol, max_iter):
    xi, nu = node_velocities(system, states, rtol, max_iter)
    return (xi, nu) + node_invariants(system, states.g, states.q, states.M, states.P, xi, nu)


SCHEMES = ("dep", "splitting")


def validate_scheme(system, x0, h, n_steps, save_every, scheme, tau, order, values=True):
    """Input checks and the scheme's defaults: (h, n_steps, save_every, τ map (None for the
    splitting), order); ``values``: :func:`validate_inputs`'."""
    val.check_choice("scheme", scheme, SCHEMES)
    if scheme == "splitting":
        if tau is not None:
            raise ValueError(f"tau: applies to scheme='dep' only (the splitting has no difference map), got {tau!r}")
        h, n_steps, save_every = validate_inputs(system, x0, h, n_steps, save_every, values)
        return h, n_steps, save_every, None, val.check_choice("order", 2 if order is None else order, SPLITTING_ORDERS)
    order = 1 if order is None else order
    h, n_steps, save_every, tau = _validate(system, x0, h, n_steps, tau or "cayley", order, save_every, values)
    return h, n_steps, save_every, tau, order


def simulate(
    system,
    x0: State,
    h,
    n_steps: int,
    *,
    scheme: str = "dep",
    tau=None,
    order: int | None = None,
    save_every: int = 1,
    throw: bool = True,
    rtol=None,
    max_newton_iterations: int = 20,
    progress: bool = False,
    checkpoint: bool = True,
    device=None,
) -> Solution:
    """Integrate ``system`` from continuous initial data ``x0``.

    ``scheme="dep"`` (default): the implicit DEP scheme. ``tau``: "cayley" (default) or "exp";
    ``order``: 1 (default; the left-point rule: seed 000's eq. 71 for the vehicle), 2
    (trapezoid, symmetric), 4 or 6 (symmetric compositions of order 2). The recursion starts
    from the continuous Legendre map (seed 000 spec §2).

    ``scheme="splitting"``: the explicit splitting of a separable ℓ = ½ξᵀJξ + ½νᵀMν − V(n, a)
    (SO(3) scenes, SO(n) with a kinetic energy diagonal in the standard basis; a scene that is
    not gets a ``ValueError`` naming the failing term), ``order`` 2 (default; Strang), 4, 6 or 8
    (:data:`vi_jax.discrete._splitting.DEFAULTS`). No Newton solve: ``rtol`` and
    ``max_newton_iterations`` do not apply, gradients are plain reverse mode. On a traced scene
    the separability check runs at run time: ``throw=True`` raises there, ``throw=False`` records
    ``NOT_SEPARABLE`` in ``Solution.result`` (NaN nodes) and costs ~0.1 ms less per call.
    A concrete call compiles once per ``n_steps // save_every``.

    DEP: ``throw=True`` raises :class:`NewtonFailure` (or an equinox runtime error under
    ``jit``) when a step fails; ``throw=False`` records it in ``Solution.result``. ``progress=True`` shows a progress bar
    (outside ``jit`` only). Jittable, vmappable and differentiable (implicit-function gradients).
    Reverse mode is checkpointed by default (memory grows with the number of saved nodes and
    blocks, not with the number of steps; the forward pass is recomputed once);
    ``checkpoint=False`` stores every step instead.

    Called on concrete inputs, one compiled program serves every ``n_steps`` with the same
    saved-node capacity (1024, or the next power of two above it) and save layout (every step
    saved, or every ``save_every``-th for any ``save_every`` > 1): the step counts are traced
    integers, and so are the sub-step fractions of orders 2, 4 and 6 (one program for the three).
    Under a transformation (``jit``, ``grad``, ``jvp``, ``vmap``) the loops have static lengths,
    also when the inputs are concrete (a scene's function may close over a traced value).
    A conservative run whose energy error says it is meaningless warns (:class:`AccuracyWarning`).
    ``device``: where a concrete run executes — None (the default device; on an accelerator a
    one-time :class:`PerformanceWarning`: single trajectories are latency-bound there), "cpu" or
    a ``jax.Device``.
    """
    h, n_steps, save_every, tau, order = validate_scheme(system, x0, h, n_steps, save_every, scheme, tau, order)
    dtype = jnp.result_type(x0.g, x0.xi, h)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    h = val.converted(h, dtype)
    cast = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    x0 = State(cast(x0.g), cast(x0.xi), cast(x0.q), cast(x0.qdot))
    n_saved = n_steps // save_every
    if scheme == "splitting":
        options = dict(order=order, method=None, arrangement=None, checkpoint=checkpoint, dtype=dtype, throw=bool(throw))
        with full_precision():
            if not val.is_eager((system, x0, h)):
                sol = simulate_splitting(system, x0, h, n_saved, save_every, progress=False, **options)
            else:
                with placement(device):
                    sol = simulate_splitting(system, x0, h, n_saved, save_every, progress=progress, looped=True, **options)
        warn_if_meaningless(sol.energy, "simulate")
        return sol
    rule, gammas = composition_coefficients(order)
    rtol = _default_rtol(dtype) if rtol is None else float(rtol)
    options = dict(tau=tau, rule=rule, gammas=gammas, rtol=rtol, max_iter=max_newton_iterations)
    with full_precision():
        if not val.is_eager((system, x0, h)):
            program = _simulate_scan_batched if val.is_batched((system, x0, h)) else _simulate_scan
            sol = program(system, x0, h, n_saved, save_every=save_every, checkpoint=bool(checkpoint), **options)
        else:
            with placement(device):
                # the trapezoid compositions (orders 2, 4, 6) as traced data: one program
                if rule != "left":
                    options["gammas"] = traced_composition(gammas)
                if progress:
                    sol = _simulate_with_progress(system, x0, h, n_saved, save_every, **options)
                else:
                    sol = _simulate_looped(system, x0, h, n_saved, save_every, **options)
    if throw:
        sol = _check_failure(sol, save_every)
    warn_if_meaningless(sol.energy, "simulate")
    return sol


def _assemble(system, state0, saved, stats, h, save_every, rtol, max_iter):
    """The Solution of the initial state ``state0`` and the ``saved`` nodes after it."""
    return _assemble_rows(system, *initial_first(state0, saved, stats), h, save_every, rtol, max_iter)


def _assemble_rows(system, states, stats, h, save_every, rtol, max_iter):
    """The Solution of the nodes ``states`` (the initial state first) and the ``stats`` of the
    steps that reached them (row 0: none)."""
    return _solution(states, stats, *_node_rows(system, states, h, save_every, rtol, max_iter))


def _node_rows(system, states, h, save_every, rtol, max_iter):
    """The times and node diagnostics of the nodes ``states``: (t, ξ, ν, energy, Kelvin–Noether,
    its scale)."""
    t = h * save_every * jnp.arange(states.M.shape[0], dtype=h.dtype)
    return (t,) + _node_diagnostics(system, states, rtol, max_iter)


def _solution(states, stats, t, xi, nu, energy, kn, kn_scale):
    """The Solution of the nodes ``states``, their ``stats`` and :func:`_node_rows`."""
    return Solution(
        t=t,
        g=states.g,
        xi=xi,
        q=states.q,
        nu=nu,
        M=states.M,
        P=states.P,
        energy=energy,
        kelvin_noether=kn,
        kelvin_noether_scale=kn_scale,
        newton_iterations=stats.iterations,
        newton_residual=stats.residual,
        result=stats.result,
    )


def _initial(system, x0):
    return legendre_initial_state(system, x0.g, x0.xi, x0.q, x0.qdot)


def _simulate_scan(system, x0, h, n_saved, *, tau, rule, gammas, save_every, rtol, max_iter, checkpoint):
    """The DEP run with static step counts (not jitted: ``vj.ensemble`` traces it under its
    own ``vmap``)."""
    state0 = _initial(system, x0)
    _, states, stats = advance_scan(system, tau, rule, gammas, h, state0, n_saved, save_every, rtol, max_iter, checkpoint)
    return _assemble_rows(system, states, stats, h, save_every, rtol, max_iter)


def _loop_nodes(system, x0, h, n_saved, save_every, *, capacity, tau, rule, gammas, rtol, max_iter):
    """The DEP loop with traced step counts: ``capacity`` + 1 node rows and their step stats."""
    state0 = _initial(system, x0)
    _, states, stats = advance_loop(system, tau, rule, gammas, h, state0, n_saved, save_every, capacity, rtol, max_iter)
    return states, stats


def _simulate_loop(system, x0, h, n_saved, save_every, *, capacity, rtol, max_iter, **options):
    """The DEP run with traced step counts, ``capacity`` + 1 node rows (not jitted)."""
    states, stats = _loop_nodes(system, x0, h, n_saved, save_every, capacity=capacity, rtol=rtol, max_iter=max_iter, **options)
    return _assemble_rows(system, states, stats, h, save_every, rtol, max_iter)


scan_program, loop_program, assemble = _simulate_scan, _simulate_loop, _assemble


def _simulate_scan_batched(*args, **kwargs):
    """``_simulate_scan`` for ``jax.vmap`` to batch: the step's products kept as dots
    (:func:`~vi_jax.lie._small.keeping_dots`; a program of its own, so that neither traced
    program is reused for the other)."""
    with keeping_dots():
        return scan_program(*args, **kwargs)


# Jitted under the same names (compile logs and tests/test_program_reuse.py name them).
_simulate_scan = eqx.filter_jit(_simulate_scan)  # traced inputs only: under a transformation
_simulate_scan_batched = eqx.filter_jit(_simulate_scan_batched)
_loop_nodes_jit = single_trajectory_jit(_loop_nodes)
_node_rows_jit = single_trajectory_jit(_node_rows)


_initial_jit = single_trajectory_jit(_initial)
_advance_loop_jit = single_trajectory_jit(advance_loop)
_assemble_jit = single_trajectory_jit(_assemble)


def _simulate_looped(system, x0, h, n_saved, save_every, **options):
    """The looped programs (traced step counts) on concrete inputs, the saved rows cut to the
    run's: the loop, then the node diagnostics, compiled side by side on their first call
    (:func:`~._overlapped_compiles.run_chained`). The second program returns only what it
    computes (:func:`_node_rows`): the saved states go to the Solution from the loop's outputs,
    not copied through it (the vehicle's concrete call, 50,000 steps: 0.98–0.99× by minima,
    0.88–0.95× by medians of 31 alternate timings in one process, loop option and default XLA,
    a throwaway A/B; the same Solution bitwise).
    The loop holds Newton's full iterations: with the Jacobian factored once per step
    (:func:`~vi_jax.solvers.lu_factor`), its steps cost 0.79–0.82× those of a
    program without them on the vehicle (orders 1, 2), 0.90–1.06× on the heavy top and the rigid
    body (``python benchmarks/newton_plan.py [--fast-loops]``), so it is run alone; ``vj.ensemble``'s
    generated step still runs the one without them first (:func:`~._ensemble.optimistically`)."""
    every = 1 if save_every == 1 else val.step_count(save_every)  # every step saved: a program of its own
    args = (system, x0, h, val.step_count(n_saved), every)
    rows = lambda nodes: (system, nodes[0], h, every, options["rtol"], options["max_iter"])  # noqa: E731
    nodes, node_rows = run_chained(_loop_nodes_jit, args, dict(capacity=saved_capacity(n_saved), **options), _node_rows_jit, rows)
    return first_rows(_solution(*nodes, *node_rows), n_saved + 1)


def _simulate_with_progress(system, x0, h, n_saved, save_every, *, tau, rule, gammas, rtol, max_iter):
    """The same computation in ≤ 100 pieces of one compiled loop, with a tqdm bar between them."""
    from tqdm.auto import tqdm

    state0 = state = _initial_jit(system, x0)
    # ξ_{k−1}, carried from piece to piece so that Newton's guesses are the plain run's; none yet:
    # NaN, as _advance.no_previous, built on the host (an eager full_like compiles a program)
    previous = np.full(state.z.shape, np.nan, state.z.dtype)
    n_chunks = min(n_saved, 100)
    sizes = [n_saved // n_chunks + (i < n_saved % n_chunks) for i in range(n_chunks)]
    capacity = saved_capacity(sizes[0])
    saved_parts, stats_parts = [], []
    with tqdm(total=n_saved * save_every, unit="step", desc="simulate") as bar:
        for size in sizes:
            (state, previous), saved, stats = _advance_loop_jit(
                system, tau, rule, gammas, h, state, val.step_count(size), val.step_count(save_every), capacity, rtol, max_iter,
                previous,
            )
            saved_parts.append(jax.tree.map(lambda x: x[1 : size + 1], saved))  # row 0: the piece's start
            stats_parts.append(jax.tree.map(lambda x: x[1 : size + 1], stats))
            bar.update(size * save_every)
    # Pad to the power-of-two capacity so the node diagnostics compile once per capacity too.
    total = saved_capacity(n_saved)
    cat = lambda *xs: jnp.concatenate(xs + (jnp.broadcast_to(xs[-1][-1:], (total - n_saved,) + xs[-1].shape[1:]),))  # noqa: E731
    saved, stats = jax.tree.map(cat, *saved_parts), jax.tree.map(cat, *stats_parts)
    return first_rows(_assemble_jit(system, state0, saved, stats, h, val.step_count(save_every), rtol, max_iter), n_saved + 1)


def _check_failure(sol: Solution, save_every: int) -> Solution:
    if val.is_concrete(sol.result):
        failed = np.asarray(sol.result) != SUCCESS  # on the host: no program to compile
        if failed.any():
            k = int(np.argmax(failed))
            code = int(sol.result[k])
            steps = f"step {k - 1}" if save_every == 1 else f"steps {(k - 1) * save_every}..{k * save_every - 1}"
            raise NewtonFailure(
                f"DEP step failed at {steps} (t ≈ {float(sol.t[k]):.6g}): {RESULT_MESSAGES.get(code, code)}; "
                f"relative residual {float(sol.newton_residual[k]):.3g} after "
                f"{int(sol.newton_iterations[k])} iterations. Reduce h, raise max_newton_iterations, "
                "or pass throw=False to inspect the partial Solution."
            )
        return sol
    return eqx.error_if(sol, jnp.any(sol.result != SUCCESS), "DEP step failed (Newton did not converge or τ singular); pass throw=False to inspect Solution.result")
