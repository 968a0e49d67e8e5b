"""Scanning a trajectory's saved nodes in blocks, for every scheme."""

import jax
import jax.numpy as jnp

SAVE_BLOCK = 128  # saved nodes per inner scan: one long output buffer costs XLA:CPU more than a step


def scan_saved_nodes(node, state, length, checkpoint=False):
    """``length`` applications of ``node(state, None) -> (state, out)`` through a two-level scan
    (blocks of ``SAVE_BLOCK`` nodes; benchmarks/step_cost.py); returns (final state, the outs
    stacked). With ``checkpoint``, reverse mode stores only the states at block boundaries and
    at the nodes, and recomputes what lies between them."""
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
    return state, jax.tree.map(lambda *xs: jnp.concatenate(xs), *pieces) if len(pieces) > 1 else pieces[0]
