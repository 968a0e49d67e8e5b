"""``simulate(scheme="splitting")``: the explicit splitting of a separable scene
(:mod:`vi_jax.discrete._splitting`) with the same :class:`Solution` as the DEP scheme."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import _validation as val
from .._system import State
from .._saved_nodes import first_rows, saved_capacity
from ..discrete._splitting import advance, advance_loop, initial_phase, nodes, resolved_parts
from ..solvers import NOT_SEPARABLE, SUCCESS
from ._compile_options import single_trajectory_jit
from ._solution import Solution, node_invariants


def _verdict(parts, nodes_):
    """A scene that failed the traced separability check (``throw=False``): its nodes after the
    first are NaN and their result is ``NOT_SEPARABLE`` (nothing silently wrong)."""
    rows = nodes_.M.shape[0]
    result = jnp.where((jnp.arange(rows) > 0) & ~jnp.asarray(parts.separable), NOT_SEPARABLE, SUCCESS).astype(jnp.int32)
    if parts.separable is True:
        return nodes_, result
    keep = lambda x: None if x is None else jnp.where(  # noqa: E731
        (result == SUCCESS).reshape((-1,) + (1,) * (x.ndim - 1)), x, jnp.nan
    )
    return jax.tree.map(keep, nodes_), result


def _diagnostics(parts, nodes_, h, save_every):
    """Energy and Kelvin–Noether at the nodes (the continuous momenta are the state)."""
    system = parts.system
    nodes_, result = _verdict(parts, nodes_)
    energy, kn, kn_scale = node_invariants(system, nodes_.g, nodes_.q, nodes_.M, nodes_.P, nodes_.xi, nodes_.nu)
    rows = nodes_.M.shape[0]
    return Solution(
        t=h * save_every * jnp.arange(rows, dtype=h.dtype),
        g=nodes_.g,
        xi=nodes_.xi,
        q=nodes_.q,
        nu=nodes_.nu,
        M=nodes_.M,
        P=nodes_.P,
        energy=energy,
        kelvin_noether=kn,
        kelvin_noether_scale=kn_scale,
        newton_iterations=jnp.zeros(rows, jnp.int32),
        newton_residual=jnp.zeros(rows, h.dtype),
        result=result,
    )


@eqx.filter_jit  # traced inputs only: under a transformation
def _run(parts, x0, h, n_saved, save_every, method, arrangement, checkpoint):
    phase0 = initial_phase(parts, x0)
    saved = advance(parts, method, arrangement, h, phase0, n_saved, save_every, checkpoint)
    return _diagnostics(parts, nodes(parts, phase0, saved), h, save_every)


@single_trajectory_jit
def _run_loop(parts, x0, h, n_saved, save_every, capacity, method, arrangement):
    phase0 = initial_phase(parts, x0)
    saved = advance_loop(parts, method, arrangement, h, phase0, n_saved, save_every, capacity)
    return _diagnostics(parts, nodes(parts, phase0, saved), h, save_every)


_initial_jit = single_trajectory_jit(initial_phase)
_advance_jit = single_trajectory_jit(advance)


@single_trajectory_jit
def _assemble(parts, phase0, saved, h, save_every):
    return _diagnostics(parts, nodes(parts, phase0, saved), h, save_every)


def _with_progress(parts, x0, h, n_saved, save_every, method, arrangement):
    """The same run in ≤ 100 pieces, with a tqdm bar between them (two compiled sizes)."""
    from tqdm.auto import tqdm

    phase0 = phase = _initial_jit(parts, x0)
    n_chunks = min(n_saved, 100)
    sizes = [n_saved // n_chunks + (i < n_saved % n_chunks) for i in range(n_chunks)]
    parts_saved = []
    with tqdm(total=n_saved * save_every, unit="step", desc="simulate") as bar:
        for size in sizes:
            saved = _advance_jit(parts, method, arrangement, h, phase, size, save_every)
            phase = jax.tree.map(lambda x: x[-1], saved)
            parts_saved.append(saved)
            bar.update(size * save_every)
    saved = jax.tree.map(lambda *xs: jnp.concatenate(xs), *parts_saved)
    return _assemble(parts, phase0, saved, h, save_every)


def simulate_splitting(
    system, x0: State, h, n_saved, save_every, *, order, method, arrangement, checkpoint, progress, dtype, throw, looped=False,
):
    """The splitting run of ``order`` as a :class:`Solution` (inputs validated by the caller).
    ``looped`` (concrete inputs): traced step counts, one program per saved-node capacity."""
    method, arrangement, parts = resolved_parts(system, dtype, order, method, arrangement, throw=throw)
    if progress:
        return _with_progress(parts, x0, h, n_saved, save_every, method, arrangement)
    if looped:
        sol = _run_loop(parts, x0, h, val.step_count(n_saved), val.step_count(save_every), saved_capacity(n_saved), method, arrangement)
        return first_rows(sol, n_saved + 1)
    return _run(parts, x0, h, n_saved, save_every, method, arrangement, bool(checkpoint))
