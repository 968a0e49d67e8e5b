"""An ensemble's members in equal groups for one compiled program (the last group padded with
copies of its last member): sliced on the host and run one after another (the progress bar), or
sliced by one program and run at the same time, one group per CPU core; then joined.

Groups at the same time (:func:`on_cores`): XLA:CPU runs a program's loops on one core (it
splits a fused operation over threads only when the operation is large, and none of a light
step's is), but runs the programs that different host threads launch side by side. The groups'
program is compiled in the calling thread (so the caller's configuration contexts — precision,
x64, default device — hold), kept for the next call of its signature
(:func:`~._kept_programs.compiled_program`), and run from worker threads.
"""

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

from ._kept_programs import compiled_program
from ._member_split import batched_leaves, pad_members

MIN_GROUP = 64  # members per group at least: the vectorised paths lose throughput on fewer
# Steps per saved node at least for groups at the same time: a run saving every node is bound by
# writing the nodes, and the groups' join copies them once more (heavy top order 1, rigid body
# order 2, with and without the loop option: 0.72-1.00x with every node saved, 1.19-1.51x with
# every fourth, 1.30-1.65x with the final node; python benchmarks/member_groups.py [--fast-loops]).
MIN_STEPS_PER_NODE = 4


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def member_group(dynamic, axes, start, size):
    """Members ``start`` … ``start + size − 1`` of the batched leaves (padded to ``size``)."""

    def take(ax, x):
        if ax is None or x is None:
            return x
        return jnp.asarray(pad_members(np.asarray(x)[start : start + size], size))  # sliced and padded on the host

    return jax.tree.map(take, axes, dynamic, is_leaf=lambda x: x is None)


def join_groups(parts, n_members):
    """The groups' results (members first) as one, without the padding."""
    return jax.tree.map(lambda *xs: jnp.asarray(np.concatenate([np.asarray(x) for x in xs])[:n_members]), *parts)


def on_cores(program, dynamic, axes, n_members, steps_per_node, *args, **kwargs):
    """``program(dynamic, *args, n_members=n_members, **kwargs)`` (an ``eqx.filter_jit``
    function whose members are independent, saving a node every ``steps_per_node`` steps) with
    the members in one group per CPU core, of at least ``MIN_GROUP``, run at the same time;
    with one group, or fewer than ``MIN_STEPS_PER_NODE`` steps per node, a plain call."""
    n_groups = min(cores(), n_members // MIN_GROUP) if steps_per_node >= MIN_STEPS_PER_NODE else 1
    if n_groups < 2:
        return program(dynamic, *args, n_members=n_members, **kwargs)
    size = -(-n_members // n_groups)
    leaves, rebuild = batched_leaves(dynamic, axes)
    groups = [rebuild(group) for group in _split(leaves, size, n_groups)]
    compiled = compiled_program(program, groups[0], *args, n_members=size, **kwargs)

    def run(group):
        return jax.block_until_ready(compiled(group, *args, n_members=size, **kwargs))

    parts = list(_workers(len(groups)).map(run, groups))
    return _joined_on_device(parts, n_members)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _split(leaves, size, n_groups):
    """Per group, its members of each leaf (the last group padded), sliced by one program. A
    slice and a transfer per leaf and group, with member 0 sliced leaf by leaf for the input
    checks (``take_member``), cost 0.7-0.9 ms more per concrete call of 1024 vehicle members
    (``python benchmarks/ensemble_call_overhead.py [--fast-loops]``)."""
    padded = [pad_members(x, size * n_groups) for x in leaves]
    return [[x[k * size : (k + 1) * size] for x in padded] for k in range(n_groups)]


@functools.partial(jax.jit, static_argnums=1)
def _joined_on_device(parts, n_members):
    """:func:`join_groups` in one program (the groups' results are on the device already)."""
    return jax.tree.map(lambda *xs: jnp.concatenate(xs)[:n_members], *parts)


def _workers(n: int) -> ThreadPoolExecutor:
    """``n`` worker threads, started once for the process: a call's groups then start at once
    (a fresh pool per call started its threads in 0.5–1 ms, a tenth of a light step's run). A
    forked child gets its own (the parent's threads do not exist there)."""
    return _pool(n, os.getpid())


@functools.cache
def _pool(n: int, pid: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(n, thread_name_prefix="vi_jax-member-group")
