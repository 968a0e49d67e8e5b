"""A trajectory's saved nodes, for every scheme: scanned in blocks (under transformations), or
written into a buffer of fixed capacity by a loop with traced counts (concrete runs)."""

import contextlib
import contextvars
import math

import jax
import jax.numpy as jnp
import numpy as np

SAVE_BLOCK = 128  # saved nodes per inner scan: one long output buffer costs XLA:CPU more than a step
SEQUENTIAL_BYTES = 512  # XLA:CPU runs a loop body's operations in order when no buffer is larger


def scan_saved_nodes(node, state, length, checkpoint=False, block=SAVE_BLOCK, *, nodes=True, blocks=True):
    """``length`` applications of ``node(state, None) -> (state, out)`` through a two-level scan
    (blocks of ``block`` nodes; benchmarks/step_cost.py); returns (final state, the outs
    stacked). With ``checkpoint``, reverse mode stores only the states at block boundaries and
    at the nodes, and recomputes what lies between them; ``nodes=False`` / ``blocks=False``
    leave the nodes / the blocks unrematerialised (for nodes whose steps are rematerialised
    one by one, :func:`each_step_rematerialised`)."""
    if checkpoint and nodes:
        node = jax.checkpoint(node)

    def scan_block(state, _):
        return jax.lax.scan(node, state, None, length=block)

    if checkpoint and blocks:
        scan_block = jax.checkpoint(scan_block)

    n_blocks, rest = divmod(length, block)
    pieces = []
    if n_blocks:
        state, out = jax.lax.scan(scan_block, state, None, length=n_blocks)
        pieces.append(jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), out))
    if rest:
        state, out = jax.lax.scan(node, state, None, length=rest)
        pieces.append(out)
    return state, jax.tree.map(lambda *xs: jnp.concatenate(xs), *pieces) if len(pieces) > 1 else pieces[0]


_IN_ONE_KERNEL = contextvars.ContextVar("vi_jax_in_one_kernel", default=False)


def one_kernel_loops() -> bool:
    """Whether the loops of a program traced now are one kernel on XLA:CPU: with the loop option
    (``vj.enable_fast_cpu_loops()``), or inside a region of :func:`in_one_kernel`."""
    from ._xla_flags import loop_option_requested
    from .engine._placement import target_platform

    return target_platform() == "cpu" and (loop_option_requested() or _IN_ONE_KERNEL.get())


def default_cpu_loops() -> bool:
    """Whether the loops of a program traced now follow XLA:CPU's default loop plan (a thunk
    per fused operation: :func:`step_block`), not one kernel per loop (:func:`one_kernel_loops`)
    or an accelerator's."""
    from .engine._placement import target_platform

    return target_platform() == "cpu" and not one_kernel_loops()


@contextlib.contextmanager
def one_kernel_plan():
    """While active, :func:`one_kernel_loops` says yes on the CPU (the loops traced are a region's)."""
    token = _IN_ONE_KERNEL.set(True)
    try:
        yield
    finally:
        _IN_ONE_KERNEL.reset(token)


# The largest loop program (jaxpr equations, nested ones counted) run as one kernel: LLVM compiles
# a kernel in one piece, in a time growing faster than its size. The vehicle's concrete DEP
# programs (jaxpr of the loops, default XLA, this version against the default plan's): order 1,
# 3,632 equations, backend compile 1.84-2.14 -> 2.03-2.78 s; orders 2/4/6 (one program), 5,471
# equations, 3.6 -> 8.0 s for steps 3-4x faster (paid back after ~400,000 steps); the heavy top
# at order 2, 2,835 equations, first call +0.7-1.0 s for steps 5-6x faster.
ONE_KERNEL_EQUATIONS = 4096


def in_one_kernel(program, default_plan=None):
    """``program`` (arrays in and out) on XLA:CPU without the loop option: traced with the
    one-kernel loop plan (:func:`one_kernel_loops`) as a region XLA:CPU compiles into one kernel
    (:func:`~vi_jax._one_kernel.one_kernel`), or, where its operations are not all such a
    kernel's (LAPACK, matrix products) or that holds more than ``ONE_KERNEL_EQUATIONS``
    equations, ``default_plan`` (the same computation for loops that are not one kernel;
    ``program`` itself if None) with the default plan. With the loop option (which makes every
    loop one kernel) ``program``; on an accelerator ``default_plan``. The region's JVP is its
    body's: differentiate a program of the default plan instead (:func:`checkpointed`)."""
    from ._one_kernel import one_kernel

    default_plan = program if default_plan is None else default_plan
    if one_kernel_loops():
        return program
    if not default_cpu_loops():
        return default_plan

    def planned(*args):
        with one_kernel_plan():
            return program(*args)

    return one_kernel(planned, fallback=default_plan, max_equations=ONE_KERNEL_EQUATIONS)


def each_step_rematerialised(step, carry, n, block):
    """``n`` applications of ``step(carry, None) -> (carry, None)``, each rematerialised in
    reverse mode (it stores the step's input carry and recomputes the step from it), scanned in
    blocks of ``block`` steps. Reverse mode would otherwise store tens of intermediate arrays a
    step, each in a buffer as long as the scan, and under XLA:CPU's default loop plan a loop
    body with a buffer larger than ``SEQUENTIAL_BYTES`` has its fused operations handed to the
    thread pool one by one (:func:`step_block`); with blocks of ``step_block(carry, False)``
    steps the inner loops, forward and transposed, hold small buffers only. Run it through
    :func:`checkpointed`: the blocks cost a program that does not differentiate."""
    step = jax.checkpoint(step, prevent_cse=False)

    def steps(carry, _):
        return jax.lax.scan(step, carry, None, length=block)[0], None

    n_blocks, rest = divmod(n, block)
    if n_blocks:
        carry = jax.lax.scan(steps, carry, None, length=n_blocks)[0]
    if rest:
        carry = jax.lax.scan(step, carry, None, length=rest)[0]
    return carry


def checkpointed(program, step, carry, *, checkpoint=True, forward=lambda program: program, forward_step=None):
    """``program(step, carry, checkpoint)`` — a loop program built from ``step(carry, None)`` —
    whose checkpoints only differentiation sees: a custom JVP whose rule is the JVP of
    ``program(…, checkpoint)`` (reverse mode transposes it, rematerialising as that program
    says) and whose value, in a program that does not differentiate, is ``program(…, False)``:
    one loop where the checkpointed program has blocks. ``forward`` wraps that value's program
    (e.g. :func:`in_one_kernel`: the rule's program keeps the default loop plan). Against a
    forward pass that ran the blocks
    (``python benchmarks/reverse_mode_plan.py`` on both versions, default XLA, under ``jit``,
    a node every 10 steps): the heavy top's splitting runs 0.45 → 0.40 µs a step (0.38 with
    ``checkpoint=False``); the vehicle's DEP traces and compiles in 4.32 → 3.49 s (3.42 without
    checkpoint; 2.82 → 2.11 s to the final state) and runs as before. What ``step`` closes
    over is hoisted into explicit arguments (``jax.closure_convert``), so gradients with respect
    to it go through the rule; the step is traced once. ``forward_step``: the same step traced
    otherwise for the value's program (e.g. Newton's iterations rolled), a second trace; the rule
    differentiates ``step``."""
    step, consts = jax.closure_convert(step, carry, None)

    def bound(step, consts):
        return lambda c, x=None: step(c, x, *consts)

    if forward_step is None:
        value, value_consts = (lambda carry, consts, _: program(bound(step, consts), carry, False)), ()
    else:
        forward_step, value_consts = jax.closure_convert(forward_step, carry, None)
        value = lambda carry, _, value_consts: program(bound(forward_step, value_consts), carry, False)  # noqa: E731

    def rule(primals, tangents):  # the value's own inputs carry nothing the rule does not have
        return jax.jvp(lambda c, k: program(bound(step, k), c, checkpoint), primals[:2], tangents[:2])

    run = jax.custom_jvp(forward(value))
    run.defjvp(rule)
    return run(carry, consts, value_consts)


def step_block(state, power_of_two=True) -> int:
    """Nodes per block when a node is a single step: the most (2 to ``SAVE_BLOCK``; a power of
    two unless ``power_of_two`` is False) whose rows of ``state``'s largest leaf fit
    ``SEQUENTIAL_BYTES``. XLA:CPU's
    thunk executor hands a loop body's fused operations to its thread pool once a buffer is
    larger; a step's operations take well under a microsecond each, so the hand-offs cost more
    than they gain (the vehicle under ``jit``, every node saved, default XLA: 50,000 steps in
    0.26 s in blocks of 4 against 0.71 s in blocks of 128 in one process, ``python
    benchmarks/step_cost.py``). A block of one node would not help: XLA inlines a loop of one
    iteration."""
    largest = max(x.size * x.dtype.itemsize for x in jax.tree.leaves(state))
    fits = max(SEQUENTIAL_BYTES // max(largest, 1), 2)
    return min(1 << (fits.bit_length() - 1) if power_of_two else fits, SAVE_BLOCK)


def rematerialised_steps(steps, carry, n):
    """``steps(carry, k) -> carry`` for ``n`` steps as ⌊√n⌋-step blocks rematerialised in
    reverse mode (then the rest): it stores O(√n) step residuals between two saved nodes."""
    inner = math.isqrt(n)
    outer, rest = divmod(n, inner)
    carry, _ = jax.lax.scan(jax.checkpoint(lambda c, _: (steps(c, inner), None)), carry, None, length=outer)
    return steps(carry, rest) if rest else carry


def loop_saved_nodes(node, carry, n_nodes, row_succeeded=None):
    """``node(k, carry) -> carry`` for k = 0 … ``n_nodes`` − 1 (traced), the carry holding the
    saved-node buffers. ``row_succeeded(carry, k)``: whether every step of node k succeeded; with
    it, no node runs after the first that did not (a concrete run's first program)."""
    if row_succeeded is None:
        return jax.lax.fori_loop(0, n_nodes, node, carry)

    def going(loop_carry):
        k, carry = loop_carry
        return (k < n_nodes) & ((k == 0) | row_succeeded(carry, jnp.maximum(k - 1, 0)))

    def next_node(loop_carry):
        k, carry = loop_carry
        return k + 1, node(k, carry)

    return jax.lax.while_loop(going, next_node, (jnp.asarray(0, jnp.int32), carry))[1]


MIN_CAPACITY = 1024


def saved_capacity(n_saved: int) -> int:
    """Saved-node buffer size (one program per capacity): at least ``MIN_CAPACITY``, so every
    run of up to 1024 saved nodes shares one program (a new capacity costs a full compile,
    seconds; the unused rows change a short call's ~10 ms by less than its run-to-run spread,
    ``python benchmarks/capacity.py``), then the next power of two."""
    return max(MIN_CAPACITY, 1 << max(n_saved - 1, 0).bit_length())


def first_rows(tree, n):
    """The first ``n`` rows of every leaf, sliced on the host: an eager device slice would
    compile a small program for every new ``n``. Each row keeps its device and its
    committedness: a committed array would make a later ``jit`` that mixes it with fresh inputs
    compile anew. An uncommitted row goes to the default device (inside
    ``vi_jax.engine._placement.placement``: the run's)."""
    leaves, treedef = jax.tree.flatten(tree)
    place = lambda x: next(iter(x.devices())) if x.committed else None  # noqa: E731
    # One device_put for all leaves: 13 apart cost 0.37 ms, more than a 100-step run's steps.
    rows = jax.device_put([np.asarray(x)[:n] for x in leaves], [place(x) for x in leaves])
    return jax.tree.unflatten(treedef, rows)
