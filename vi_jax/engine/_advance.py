"""Advancing a DEP state over many steps, saving nodes: two loop programs with the same step.

* :func:`advance_scan` — static lengths (``lax.scan``): forward- and reverse-differentiable,
  with optional rematerialisation (``checkpoint``). Used whenever ``simulate`` is traced
  (under ``jit``, ``grad``, ``jvp``, ``vmap``).
* :func:`advance_loop` — the number of nodes and the steps per node are *traced* integers
  (``lax.fori_loop`` → ``while``) writing into a buffer of static ``capacity``: one compiled
  program serves every ``n_steps`` whose node count fits the capacity (``simulate`` rounds
  the capacity up to a power of two). Not reverse-differentiable, so used only on concrete
  inputs, where nothing differentiates the call. There the fractions of the trapezoid
  compositions are traced too (:class:`TracedComposition`): orders 2, 4 and 6 share one program.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._one_kernel import kernel_equations
from .._saved_nodes import (
    ONE_KERNEL_EQUATIONS,
    SAVE_BLOCK,
    checkpointed,
    default_cpu_loops,
    each_step_rematerialised,
    in_one_kernel,
    loop_saved_nodes,
    one_kernel_loops,
    rematerialised_steps,
    scan_saved_nodes,
    step_block,
)
from ..discrete import StepStats, dep_step
from ..lie._small import batched_by_vmap
from ..solvers import SUCCESS
from ..solvers._newton import rolled_iterations
from ._explicit_unknowns import explicit_unknowns
from ._placement import target_platform


def _sub_step(system, tau, rule, rtol, max_iter):
    def sub_step(state, gamma_h):
        explicit = explicit_unknowns(system, tau, rule, state, gamma_h)
        new, stats = dep_step(system, tau, rule, gamma_h, state, rtol=rtol, max_iterations=max_iter, explicit=explicit)
        # After a failed step the state is NaN (and every later step reports NONFINITE): a
        # partial Solution never continues from a state that did not solve the equations.
        failed = stats.result != SUCCESS
        return jax.tree.map(lambda x: jnp.where(failed, jnp.nan, x), new), stats

    return sub_step


MAX_SUB_STEPS = 9  # the longest composition (order 6, Kahan & Li's 9 stages)


class TracedComposition(eqx.Module):
    """A composition's sub-step fractions γ_i as traced data, zero-padded to ``MAX_SUB_STEPS``,
    with their number: the loop programs of orders 2, 4 and 6 are one compiled program (one
    compile instead of three; steps 0.6–1.4× the static ones, within the run-to-run spread,
    default XLA and the loop option: ``python benchmarks/composition_program.py``)."""

    fractions: Float[Array, " max_sub_steps"]
    count: Int[Array, ""]


def traced_composition(gammas) -> TracedComposition:
    """The sub-step fractions ``gammas`` as a :class:`TracedComposition`."""
    padded = np.zeros(MAX_SUB_STEPS)
    padded[: len(gammas)] = gammas
    return TracedComposition(jnp.asarray(padded), jnp.asarray(len(gammas), jnp.int32))


def _repeat_keeping_worst(step, state, n):
    """``n`` (traced) applications of ``step(state, i) -> (state, stats)``; the stats are the
    elementwise maximum over them, from :meth:`StepStats.zeros`."""

    def body(i, carry):
        state, stats = step(carry[0], i)
        return state, jax.tree.map(jnp.maximum, carry[1], stats)

    return jax.lax.fori_loop(0, n, body, (state, StepStats.zeros(_dtype(state))))


def _dtype(carry):
    """The unknowns' dtype: z is the last leaf of a StepState, ξ_{k−1} that of (state, ξ_{k−1})."""
    return jax.tree.leaves(carry)[-1].dtype


def no_previous(z):
    """ξ_{k−1} before the first step: none (NaN), see :func:`extrapolation`."""
    return jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), z)


def extrapolation(z, z_prev):
    """Newton's first guess from the unknowns ξ_k and ξ_{k−1} (arrays, or tuples of member
    arrays): 2ξ_k − ξ_{k−1}, or ξ_k while ξ_{k−1} is NaN (:func:`no_previous`); and ``after``,
    the solution of the step ↦ the next step's ξ_{k−1}. The first two steps so start from the
    last velocity: the first from the continuous one, which at large h·|ξ| differs from the
    discrete ones by far more than a step's change."""
    first = ~jnp.isfinite(jax.tree.leaves(z_prev)[0])
    guess = jax.tree.map(lambda a, b: jnp.where(first, a, 2 * a - b), z, z_prev)

    def after(z_new):
        return jax.tree.map(lambda new, a: jnp.where(first, new, a), z_new, z)

    return guess, after


def _one_step(system, tau, rule, gammas, h, rtol, max_iter):
    """One (composed) step of the carry (state, ξ_{k−1}); Newton statistics are the worst over
    its sub-steps. A single-stage step (orders 1 and 2) starts Newton from the extrapolation
    2ξ_k − ξ_{k−1} (error O(h²), against O(h) for ξ_k: at h = 0.01 the heavy top needed
    Newton's fallback iterations in 39% of its steps from ξ_k and in none from it, ``python
    benchmarks/extrapolated_guess.py``); a composition starts each sub-step from the last one."""
    sub_step = _sub_step(system, tau, rule, rtol, max_iter)

    def one_step(carry, _=None):
        state, z_prev = carry
        extrapolated, after = extrapolation(state.z, z_prev)
        if isinstance(gammas, TracedComposition):  # a loop of traced length over the fractions
            guess = jnp.where(gammas.count == 1, extrapolated, state.z)
            fraction_step = lambda s, i: sub_step(s, gammas.fractions[i].astype(h.dtype) * h)  # noqa: E731
            new, stats = _repeat_keeping_worst(fraction_step, _guessing(state, guess), gammas.count)
        elif len(gammas) == 1:
            new, stats = sub_step(_guessing(state, extrapolated), gammas[0] * h)
        else:
            # A rolled loop over the composition's sub-steps: one copy of the step to compile.
            new, stats = jax.lax.scan(sub_step, state, jnp.asarray(gammas, h.dtype) * h)
            stats = jax.tree.map(lambda x: jnp.max(x, axis=0), stats)
        return (new, after(new.z)), stats

    return one_step


def _with_previous(state):
    """The loop carry (state, ξ_{k−1}) before the first step."""
    return state, no_previous(state.z)


def _guessing(state, guess):
    """``state`` with Newton's first guess ``guess`` in place of the last step's unknowns."""
    return eqx.tree_at(lambda s: s.z, state, guess)


def advance_scan(system, tau, rule, gammas, h, state, length, save_every, rtol, max_iter, checkpoint=False):
    """``length`` saved nodes of ``save_every`` steps each; returns (final state, states, stats),
    the last two with ``length`` + 1 rows: row 0 the initial state with zero stats, row k + 1 node k.

    Nodes are saved through a two-level scan (blocks of ``SAVE_BLOCK`` nodes, of
    :func:`step_block` nodes when every step is saved): writing every step's state straight
    into one long output buffer costs XLA:CPU more than the step itself
    (benchmarks/step_cost.py). With ``checkpoint``, reverse mode stores only the state at block
    boundaries (and at saved nodes) and recomputes the steps inside a block; the steps between
    two saved nodes run as √save_every rematerialised blocks, so memory grows like
    n/(block·save_every) + block + √save_every states (benchmarks/gradients.py). On XLA:CPU's
    default loop plan every step is rematerialised by itself instead of each node
    (:func:`~vi_jax._saved_nodes.each_step_rematerialised`; with every step saved, each node
    and not its block): reverse mode then holds no buffer of a block's length of a step's
    intermediate values, whose loops XLA:CPU runs operation by operation on its thread pool.
    The vehicle's gradient over 4,000 steps took 9.1 / 9.0 / 7.6 µs a step against
    24.2 / 14.2 / 13.5 (the final state; a node every 10 steps; every step), 1.7–1.8 µs for the
    forward pass (default XLA, ``python benchmarks/reverse_mode_plan.py``). With the loop
    option and every step saved, the nodes are one scan (:func:`_initial_node_in_scan`) and
    reverse mode stores a state per node, as many as the saved nodes (vehicle, 10⁶ steps, the
    positions' gradient: 289 MB of XLA temporaries, against 50 MB in blocks of 128 nodes).
    Only differentiation sees these checkpoints: a program that does not differentiate runs the
    loops of ``checkpoint=False`` (:func:`~vi_jax._saved_nodes.checkpointed`). Where those loops
    are one kernel, a single trajectory's step is the concrete call's (:func:`_value_step`).
    """

    carry = _with_previous(state)
    one_step = _one_step(system, tau, rule, gammas, h, rtol, max_iter)

    def program(one_step, carry, checkpoint):
        return _scanned_nodes(one_step, carry, length, save_every, checkpoint)

    # The program of checkpoint=False unless differentiated, one kernel where it can be.
    value_step = _value_step(lambda gammas: _one_step(system, tau, rule, gammas, h, rtol, max_iter), gammas, carry)
    forward = in_one_kernel if len(gammas) == 1 or value_step is not None else _default_plan
    # Differentiation runs the default plan's loops, one kernel only with the loop option.
    rolled_rule = value_step is not None and len(gammas) == 1 and one_kernel_loops()
    differentiated = value_step if rolled_rule else one_step
    return checkpointed(program, differentiated, carry, checkpoint=checkpoint, forward=forward, forward_step=value_step)


def _with_rolled_iterations(step):
    """``step`` traced with Newton's iterations rolled."""

    def rolled(*args):
        with rolled_iterations():
            return step(*args)

    return rolled


def _value_step(make_step, gammas, carry):
    """The step of :func:`advance_scan`'s value program, where it differs from
    ``make_step(gammas)``'s, or None: as in the concrete call's one-kernel loops, Newton's
    iterations rolled (:func:`~vi_jax.solvers._newton.rolled_iterations`) and a composition's
    sub-steps (orders 4, 6) a loop of a count XLA does not know (a :class:`TracedComposition`
    behind an optimisation barrier: XLA:CPU aborts compiling a one-kernel region whose loop over
    the sub-steps has a known count, :func:`_default_plan`). On XLA:CPU, for a step no ``jax.vmap``
    batches (:func:`~vi_jax.lie._small.batched_by_vmap`), whose jaxpr so traced is a one-kernel
    region's (:func:`~vi_jax._one_kernel.kernel_equations`, at most ``ONE_KERNEL_EQUATIONS``).
    Differentiation keeps ``make_step(gammas)`` (:func:`~vi_jax._saved_nodes.checkpointed`),
    rolled for orders 1, 2 with the loop option only (the rule's loops are one kernel only then).

    Under ``jit`` the vehicle's order-2 loops are then one kernel (5,490 → 2,934 equations): its
    steps 0.34× as long with default XLA, the other cases' at orders 1 and 2 0.56–1.06×, their
    gradients with the loop option 0.77–1.03×; at orders 4 and 6 0.19–0.32× with default XLA,
    0.83–1.06× with the loop option (``python
    benchmarks/rolled_under_jit.py [--fast-loops]``). Where the loops are not one kernel, rolled
    iterations cost more than they save (throwaway A/Bs when this was written, under ``jit``,
    default XLA: SO(4)'s rigid body, whose step calls LAPACK, 8.4 → 10.4 µs a step; a plain
    ``vmap`` of ``vj.simulate`` over 256 members 1.1–2.4× slower, but for the vehicle at order 1;
    the rigid body's gradients 1.08–1.11× as long, in two runs of that benchmark's first form,
    which rolled them with default XLA too)."""
    if target_platform() != "cpu" or batched_by_vmap():
        return None
    if len(gammas) > 1:
        gammas = jax.lax.optimization_barrier(traced_composition(gammas))
    step = _with_rolled_iterations(make_step(gammas))
    # Traced as checkpointed traces it (jax.closure_convert keeps the trace for its second call);
    # the equations counted on the converted step, a replay of that trace.
    converted, consts = jax.closure_convert(step, carry, None)
    equations = kernel_equations(jax.make_jaxpr(converted)(carry, None, *consts).jaxpr)
    return step if equations is not None and equations <= ONE_KERNEL_EQUATIONS else None


def _default_plan(program):
    """``program`` on XLA:CPU's default loop plan: the forward program of a composition (orders 4
    and 6) under a transformation, where :func:`_value_step` has no step of its own (a ``vmap``,
    an accelerator, a step beyond one kernel). XLA:CPU aborts the process compiling a one-kernel
    region whose step holds the rolled loop over the sub-steps of static length (jax 0.10.2:
    "Check failed: slice_to_buffer_table_index_.empty() || has_explicit_index", the heavy top and
    the rigid body at orders 4 and 6 under ``jit``; unrolled, or with the concrete call's traced
    count, it compiles; tests/test_simulate_one_kernel.py)."""
    return program


def _scanned_nodes(one_step, carry, length, save_every, checkpoint):
    """:func:`advance_scan`'s loops over the carry (state, ξ_{k−1}) of ``one_step``."""
    state = carry[0]
    each_step = checkpoint and default_cpu_loops()  # steps rematerialised one by one

    def worst_step(carry, _):
        state, stats = one_step(carry[0])
        return (state, jax.tree.map(jnp.maximum, carry[1], stats)), None

    def worst_steps(carry, n):  # the worst statistics so far, carried (stacking every step's
        # statistics costs XLA:CPU three writes per step: 0.52 → 0.14 s for 50,000 steps)
        if each_step:
            return each_step_rematerialised(worst_step, carry, n, step_block(carry, power_of_two=False))
        return jax.lax.scan(worst_step, carry, None, length=n)[0]

    def node_steps(carry):
        carry = (carry, StepStats.zeros(_dtype(carry)))
        if not checkpoint or save_every <= SAVE_BLOCK:
            return worst_steps(carry, save_every)
        return rematerialised_steps(worst_steps, carry, save_every)

    def node(carry, _):
        carry, stats = one_step(carry, None) if save_every == 1 else node_steps(carry)
        return carry, (carry[0], stats)

    if _initial_node_in_scan(save_every):
        node = _initial_node_first(node, StepStats.zeros(_dtype(state)))
        (_, (state, _)), (rows, stats) = scan_saved_nodes(node, (True, carry), length + 1, checkpoint, length + 1)
        return state, rows, stats
    block = _node_block(state, save_every)
    remat = {}
    if each_step:  # a node of one step is rematerialised, not its block; else its steps, not it
        remat = dict(blocks=False) if save_every == 1 else dict(nodes=False)
    (final, _), (saved, stats) = scan_saved_nodes(node, carry, length, checkpoint, block, **remat)
    return (final,) + initial_first(state, saved, stats)


def initial_first(state0, saved, stats):
    """The rows of the initial state ``state0`` (zero stats) and of the ``saved`` nodes after it."""
    first = lambda x0, x: jnp.concatenate([jnp.asarray(x0, x.dtype)[None], x])  # noqa: E731
    return jax.tree.map(first, state0, saved), jax.tree.map(first, StepStats.zeros(_dtype(state0)), stats)


def _initial_node_in_scan(save_every):
    """Whether :func:`advance_scan` scans its nodes with the initial state as the first
    (:func:`_initial_node_first`), in one scan: every step saved on the CPU where the whole loop
    is one kernel (:func:`~vi_jax._saved_nodes.one_kernel_loops`: the loop option, or a
    region). Otherwise it copies the initial state in front of the nodes: XLA:CPU's default loop
    plan needs its blocks of steps (:func:`_node_block`), and a node of ``save_every`` > 1 steps
    would be computed once more for nothing."""
    return save_every == 1 and one_kernel_loops()


def _initial_node_first(node, zero):
    """``node`` for a scan of one more node whose carry holds a flag ``first`` (True at the
    start): the first node returns the initial state with ``zero`` stats, the others step. The
    first node's step is computed and dropped (a ``where``, one step in the run: a conditional
    cost more per step than it saves), the same step the second node takes, so its value is
    finite wherever the run is. With the loop option, every node saved, the vehicle under
    ``jit`` ran 50,000 steps in 1.90–2.08× the time of the hand-written eq. (88) against
    2.30–2.40× with the initial state copied in front of the nodes (three runs of ``python
    benchmarks/step_cost.py`` with the loop option, its row "initial state copied in front")."""

    def first_or_node(carry, _):
        first, carry = carry
        new, out = node(carry, None)
        keep = lambda a, b: jax.tree.map(lambda x, y: jnp.where(first, x, y), a, b)  # noqa: E731
        return (jnp.asarray(False), keep(carry, new)), keep((carry[0], zero), out)

    return first_or_node


def _node_block(state, save_every):
    """Saved nodes per block of :func:`advance_scan`: :func:`step_block` when every step is
    saved under XLA:CPU's default loop plan (where a step's operations would otherwise share a
    loop body with the block's large output buffers), else ``SAVE_BLOCK`` (with the loop option
    a run saving every step does not ask: :func:`_initial_node_in_scan`)."""
    if save_every == 1 and default_cpu_loops():
        return step_block(state)
    return SAVE_BLOCK


def advance_loop(system, tau, rule, gammas, h, state, n_nodes, save_every, capacity, rtol, max_iter, previous=None):
    """``n_nodes`` (traced, ≤ ``capacity``) saved nodes of ``save_every`` (traced, or the static
    1: :func:`_every_step_in_blocks`) steps each; ``gammas`` may be a :class:`TracedComposition`.
    ``previous``: the unknowns ξ_{k−1} of the step before ``state`` (Newton's extrapolated first
    guess, :func:`extrapolation`), as a run continued in pieces carries them; None before the
    first step.

    Returns (final carry (state, ξ_{k−1}), saved states, stats), the last two with
    ``capacity`` + 1 rows: row 0 the initial state with zero stats, row k + 1 node k; rows past
    ``n_nodes`` repeat the initial state (valid data for the node diagnostics) with zero stats. The buffers start as
    the initial state, so the Solution's rows need no copy to put it first (a copy of every
    saved array: the vehicle's concrete call with every step saved, 50,000 steps, 2.46–2.73× →
    2.38–2.53× the hand-written eq. (88) with the loop option, 1.40–1.44× → 1.37–1.40× with
    default XLA, timing the hand code and the concrete call of ``python benchmarks/step_cost.py``
    alternately in processes of both versions; that benchmark's row "concrete call, every node
    saved" on this version: 2.28× and 1.39×).

    Where the loops are one kernel, Newton's iterations are rolled
    (:func:`~vi_jax.solvers._newton.rolled_iterations`): the residual and its Jacobian compiled
    once each. Against the version before, in alternate processes on a slow day (``python
    benchmarks/compile_time.py``, default XLA; its row "Newton's iterations unrolled" is the peer
    in one process): the vehicle's first call (order 1, 20,000 steps) 4.04–4.26 → 3.15–3.48 s
    (the peer 3.20–4.08 s), its steps 0.86–1.04 → 0.86–1.13 µs; at order 2, whose unrolled
    loops are too large for one kernel, 5.3–7.5 → 6.2–6.3 s and 14.1–16.8 → 5.6–5.7 µs a step;
    the heavy top at order 2 4.5–4.7 → 2.1–2.3 s, 2.0–2.1 → 1.9–2.0 µs a step.
    """
    one_step = _one_step(system, tau, rule, gammas, h, rtol, max_iter)

    def loops(carry, n_nodes, save_every):
        state = carry[0]
        saved = jax.tree.map(lambda x: jnp.broadcast_to(x, (capacity + 1,) + x.shape), state)
        stats = jax.tree.map(lambda s: jnp.broadcast_to(s, (capacity + 1,)), StepStats.zeros(state.z.dtype))
        if save_every is None:
            return _every_step_in_blocks(one_step, carry, saved, stats, n_nodes)

        def node(k, carry):
            carry, saved, stats = carry
            carry, worst = _repeat_keeping_worst(lambda c, _: one_step(c), carry, save_every)
            put = lambda buf, x: jax.lax.dynamic_update_index_in_dim(buf, x, k + 1, 0)  # noqa: E731
            return carry, jax.tree.map(put, saved, carry[0]), jax.tree.map(put, stats, worst)

        return loop_saved_nodes(node, (carry, saved, stats), n_nodes)

    def rolled_loops(*args):
        with rolled_iterations():
            return loops(*args)

    every_step = isinstance(save_every, int) and save_every == 1  # None: a program of its own
    carry = _with_previous(state) if previous is None else (state, previous)
    return in_one_kernel(rolled_loops, default_plan=loops)(carry, n_nodes, None if every_step else save_every)


def _every_step_in_blocks(one_step, carry, saved, stats, n_nodes):
    """:func:`advance_loop` with every step saved: a loop over blocks of :func:`step_block`
    steps (the capacity is a multiple of it), each a scan of static length written into the
    buffers at once, as :func:`advance_scan` does; the steps of the last block past ``n_nodes``
    leave the state as it is and their rows repeat the initial state. The step's loop then has
    a known trip count and no large buffer: the vehicle's looped program ran 0.87–0.93× as long
    as with a node loop and a step loop of traced lengths, default XLA (python
    benchmarks/step_cost.py, its row "concrete call, every node saved, traced save_every")."""
    state = carry[0]
    block = step_block(state)
    capacity = saved.z.shape[0] - 1
    if capacity % block:
        raise ValueError(f"capacity: expected a multiple of {block} (the block of steps), got {capacity}")
    zero = StepStats.zeros(state.z.dtype)
    keep_if = lambda keep, new, old: jax.tree.map(lambda a, b: jnp.where(keep, a, b), new, old)  # noqa: E731

    def nodes(b, carry):
        carry, saved, stats = carry

        def node(carry, i):
            keep = b * block + i < n_nodes
            new, step_stats = one_step(carry)
            new = keep_if(keep, new, carry)
            return new, (keep_if(keep, new[0], state), keep_if(keep, step_stats, zero))

        carry, (rows, row_stats) = jax.lax.scan(node, carry, jnp.arange(block))
        put = lambda buf, x: jax.lax.dynamic_update_slice_in_dim(buf, x, 1 + b * block, 0)  # noqa: E731
        return carry, jax.tree.map(put, saved, rows), jax.tree.map(put, stats, row_stats)

    n_blocks = (n_nodes + block - 1) // block
    return jax.lax.fori_loop(0, n_blocks, nodes, (carry, saved, stats))
