"""The loops of the batched kernels: steps of every member at once (tuples of member arrays as
the carry), saved nodes packed one row per node, per-member Newton statistics kept as the worst
since the last saved node."""

import jax
import jax.numpy as jnp

from .._saved_nodes import SAVE_BLOCK, loop_saved_nodes, rematerialised_steps, scan_saved_nodes
from ..solvers import SUCCESS


def no_stats(n_members, dtype):
    """(iterations, residual, result) of no step: the start of a running maximum."""
    return (jnp.zeros((n_members,), jnp.int32), jnp.zeros((n_members,), dtype), jnp.zeros((n_members,), jnp.int8))


def _pack(rows, carry, stats, dtype):
    """One packed row per node: a write per saved array costs more than the arithmetic."""
    return jnp.stack(rows(carry)), jnp.stack([x.astype(dtype) for x in stats])


def scan_member_nodes(worst_step, carry0, rows, n_saved, save_every, checkpoint, n_members, dtype, unroll=1):
    """``n_saved`` nodes of ``save_every`` steps (static counts: what ``jit``, ``grad`` and
    ``vmap`` trace). ``worst_step((carry, worst), None) -> ((carry, worst), None)``; ``rows(carry)``:
    the member arrays saved at a node. Returns the packed rows (nodes, components, members) and
    statistics (nodes, 3, members). ``checkpoint``: reverse mode rematerialises as
    ``vj.simulate``'s (states stored at blocks of saved nodes, √save_every blocks of steps
    between two nodes); the forward pass is unchanged. ``unroll``: steps per iteration of the
    step loop."""

    def worst_steps(carry, n):
        return jax.lax.scan(worst_step, carry, None, length=n, unroll=unroll)[0]

    def node(carry, _):
        carry = (carry, no_stats(n_members, dtype))
        if not checkpoint or save_every <= SAVE_BLOCK:
            carry = worst_steps(carry, save_every)
        else:
            carry = rematerialised_steps(worst_steps, carry, save_every)
        return carry[0], _pack(rows, *carry, dtype)

    return scan_saved_nodes(node, carry0, n_saved, checkpoint)[1]


def loop_member_nodes(worst_step, carry0, rows, n_saved, save_every, capacity, n_members, dtype, stop_at_failure=False):
    """The same with traced ``n_saved`` (≤ ``capacity``) and ``save_every``: one program for every
    run length. Rows past ``n_saved`` repeat the initial state with zero statistics.
    ``stop_at_failure``: no node after the first where some member's step did not succeed (the
    rows past it then repeat the initial state too)."""
    first, none = _pack(rows, carry0, no_stats(n_members, dtype), dtype)

    def node(k, loop_carry):
        carry, saved, stats = loop_carry
        carry = jax.lax.fori_loop(0, save_every, lambda _, c: worst_step(c, None)[0], (carry, no_stats(n_members, dtype)))
        row, row_stats = _pack(rows, *carry, dtype)
        put = lambda buffer, x: jax.lax.dynamic_update_index_in_dim(buffer, x, k, 0)  # noqa: E731  (not a scatter: one_kernel)
        return carry[0], put(saved, row), put(stats, row_stats)

    buffers = (jnp.broadcast_to(first, (capacity,) + first.shape), jnp.broadcast_to(none, (capacity,) + none.shape))
    succeeded = (lambda loop_carry, k: jnp.all(loop_carry[2][k, 2] == SUCCESS)) if stop_at_failure else None
    _, saved, stats = loop_saved_nodes(node, (carry0, *buffers), n_saved, succeeded)
    return saved, stats
