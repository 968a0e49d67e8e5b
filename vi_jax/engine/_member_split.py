"""An ensemble's member axis: which leaves carry it, chunks of members run one after another (the
CPU plan of the batched kernels) and padding to a multiple of a group size (devices, progress
groups)."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def pad_members(x, size):
    """``x`` (members first) with copies of its last member appended up to ``size`` members
    (a NumPy array is padded on the host: no program to compile)."""
    if x.shape[0] == size:
        return x
    xp = np if isinstance(x, np.ndarray) else jnp
    return xp.concatenate([x, xp.repeat(x[-1:], size - x.shape[0], axis=0)])


# Members per inner loop of the batched kernel on CPU, its loops one kernel: of 64, 256, 512 and
# 1024 members, 64 ran fastest for four of seven scenes and within 0.89x of the fastest for the
# rest, default XLA (python benchmarks/ensemble_chunks.py).
CHUNK = 64


def in_chunks(dynamic, static, axes, n_members, chunk, kernel):
    """``kernel(system, x0, n_members)`` (a batched kernel with the run's other arguments bound)
    over chunks of at most ``chunk`` members, one chunk after the other (None: all members at once). On
    CPU (``CHUNK``) the working set of a chunk stays in cache, and XLA:CPU runs a small loop as
    one kernel rather than one dispatch per fused operation (several times faster per member); a
    GPU wants the whole batch in every kernel (``benchmarks/ensemble_gpu.py``)."""
    if chunk is None or n_members <= chunk:
        return kernel(*eqx.combine(dynamic, static), n_members)
    n_chunks = -(-n_members // chunk)
    chunk = -(-n_members // (8 * n_chunks)) * 8  # as few padded copies as whole SIMD lanes allow
    padded = n_chunks * chunk
    is_none = lambda x: x is None  # noqa: E731

    def split(ax, x):
        if ax is None or x is None:
            return x
        return pad_members(x, padded).reshape((n_chunks, chunk) + x.shape[1:])

    batched = jax.tree.map(split, axes, dynamic, is_leaf=is_none)
    shared = jax.tree.map(lambda ax, x: x if ax is None else None, axes, dynamic, is_leaf=is_none)
    chunked = jax.tree.map(lambda ax, x: None if ax is None else x, axes, batched, is_leaf=is_none)

    def one(members):
        merged = jax.tree.map(lambda a, b: a if b is None else b, shared, members, is_leaf=is_none)
        return kernel(*eqx.combine(merged, static), chunk)

    out = jax.lax.map(one, chunked)
    return jax.tree.map(lambda x: x.reshape((padded,) + x.shape[2:])[:n_members], out)


def leaf_axes(name, tree, axes):
    """The axis (0 or None) of every leaf of ``tree`` from a prefix ``axes`` (as jax.vmap)."""

    def expand(ax, sub):
        if ax is not None and (isinstance(ax, bool) or ax != 0):
            raise ValueError(f"{name}: expected 0 (batched), None (shared) or a pytree prefix of them, got {ax!r}")
        return jax.tree.map(lambda leaf: ax if eqx.is_array(leaf) else None, sub)

    try:
        return jax.tree.map(expand, axes, tree, is_leaf=lambda x: x is None)
    except (TypeError, ValueError) as err:
        if str(err).startswith(name):
            raise
        raise ValueError(f"{name}: expected 0, None or a pytree prefix of the argument; {err}") from err


def member_counts(name, tree, axes):
    counts = []

    def visit(ax, leaf):
        if ax == 0:
            if jnp.ndim(leaf) == 0:
                raise ValueError(f"{name}: a batched leaf needs a leading member axis, got a scalar")
            counts.append(jnp.shape(leaf)[0])

    jax.tree.map(visit, axes, tree, is_leaf=lambda x: x is None)
    return counts


def batched_leaves(tree, axes):
    """The batched leaves of ``tree`` (axis 0 in ``axes``) and ``rebuild(new leaves)``: ``tree``
    with them replaced."""
    is_none = lambda x: x is None  # noqa: E731
    flat_axes = jax.tree.leaves(axes, is_leaf=is_none)
    leaves, treedef = jax.tree.flatten(tree, is_leaf=is_none)
    batched = [i for i, ax in enumerate(flat_axes) if ax is not None and leaves[i] is not None]

    def rebuild(new):
        out = list(leaves)
        for i, x in zip(batched, new):
            out[i] = x
        return jax.tree.unflatten(treedef, out)

    return [leaves[i] for i in batched], rebuild


def take_member(tree, axes, index):
    """Member ``index`` of the batched leaves of ``tree``, sliced by one program (an eager slice
    per leaf dispatches a program each)."""
    leaves, rebuild = batched_leaves(tree, axes)
    return rebuild(_members_at(leaves, index))


@functools.partial(jax.jit, static_argnums=1)
def _members_at(leaves, index):
    return [x[index] for x in leaves]
