"""Ensembles: :func:`vi_jax.simulate` over a batch of initial states and/or parameters, with
the members on the vectorised axis, and sharding of the member axis over devices.

The code paths return the same :class:`~vi_jax.Solution` (leading axis = member), equal to
``vj.simulate`` member by member (to round-off; tests/test_ensemble.py,
tests/test_generated_step.py):

- ``method="batched"`` (the default through ``"auto"``) — the step generated from the scene's
  Lagrangian (:mod:`._generated_step`), any scene, τ and order: ``vj.simulate``'s DEP step run on
  *component arrays* of shape (members,), so every operation of a step is an elementwise loop
  over the members and XLA fuses a whole Newton iteration into one vectorised loop; unknowns
  with explicit equations are solved before Newton (:func:`~._member_newton.explicit_block`).
  No path names a model (the vehicle's hand-written step is the benchmarks' peer: at order 1 the
  generated step runs 1.51–1.58× its rate with default XLA, 1.00–1.03× with the loop option,
  ``python benchmarks/explicit_block.py [--fast-loops]``). The plan
  follows the platform (:func:`target_platform`): on CPU the members go through chunks of
  ``CHUNK`` one after another (cache-sized), each chunk's loops one kernel
  (:func:`~vi_jax._one_kernel.one_kernel`); on a GPU the whole batch is in every kernel (H100,
  the heavy top at order 1: 2.47 G member-steps/s in float64 at 2²⁰ members; a chunked plan ran
  50× slower; README, ``benchmarks/ensemble_gpu.py``), with a speculative step under ``jit``
  (:func:`~._generated_step._speculative`: the fallback iterations rerun the whole step, for
  the batch, only where a member needs them; H200, the vehicle at order 1: 3.09 G in float64,
  ``benchmarks/gpu_step_profile.py``). A concrete call on CPU (no ``mesh``, a node saved every 4 steps or more)
  splits the members into one group per core (:func:`~._member_groups.on_cores`), run at the
  same time from worker threads: XLA:CPU runs one program's loops on one core.
- ``method="vmap"`` — ``jax.vmap`` of ``vj.simulate``'s DEP program. On CPU its small products
  are traced as batched dots (``batched_products``). Every 3×3 or 6×6 array keeps its tiny
  dimensions innermost, which XLA:CPU vectorises poorly.

Speeds: ``python benchmarks/ensemble_vs_vmap.py [--fast-loops]``.

Newton in every path follows ``vj.simulate`` (one Newton step, two chord steps, a check, a final
correction; the generated step on CPU may start from factors carried from an earlier step where
its Jacobian is costly, and where its residual is costly checks each chord iterate, each member
stopping at its first converged one as a concrete ``vj.simulate`` does): the chord steps so
checked and the fallback iterations run only while some member has not converged, and only the
unconverged members are updated, so per-member results do not depend on the other members (nor
on how the ensemble is sharded). Per-member convergence is in ``Solution.newton_iterations``,
``newton_residual`` and ``result`` (shape (members, nodes)); :func:`member_converged` sums it up.

Several devices: pass ``mesh`` (e.g. ``jax.make_mesh((jax.device_count(),), ("members",))``);
each device integrates its share of the members with no communication (``jax.shard_map``).
Multi-host: call ``jax.distributed.initialize()`` in every process first; ``jax.devices()``
then lists every host's devices, the same call on every process with the same inputs runs each
host's share, and ``jax.experimental.multihost_utils.process_allgather`` collects the result
(docs/ensembles_and_fitting.md).
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

from .. import _validation as val
from .._accuracy import warn_if_meaningless
from .._precision import full_precision
from ..discrete._composition import composition_coefficients
from ..lie._small import batched_products, keeping_dots
from ._simulate import NewtonFailure, Solution, _default_rtol, loop_program, scan_program, simulate, validate_scheme
from ..solvers import CHORD_ITERATIONS, RESULT_MESSAGES, SUCCESS
from .._system import State
from ._compile_options import ENSEMBLE_OPTIONS, cpu_options_jit
from ._placement import target_platform
from ._member_groups import MIN_GROUP, join_groups, member_group, on_cores
from ._member_split import CHUNK as CHUNK, in_chunks, leaf_axes, member_counts, pad_members, take_member
from ._generated_step import generated_loop, generated_scan, generated_solution, zero_entries

METHODS = ("auto", "batched", "vmap")
# The generated step folds the scene's parameter entries that are exactly zero for every member
# where their values are known when the step is traced (a concrete call, or a scene a caller's
# jit closes over; zero_entries: a diagonal inertia's off-diagonal entries; a program per pattern
# of zeros); False: the benchmark's switch. python benchmarks/folded_zeros.py [--fast-loops]
# (1024 members): concrete calls 1.13-1.58x faster (default XLA; 1.03-1.72x with the loop option)
# across the rigid body, heavy top and vehicle at orders 1 and 2, 1.12-1.75x under such a jit (the
# heavy top at order 2 fastest: its residual 453 -> 287 operations per member; the vehicle at
# order 1: 266 -> 214, 1.13-1.21x).
FOLD_ZEROS = True


# --- the public API ----------------------------------------------------------------------


def vary(tree, **fields):
    """A copy of ``tree`` (a system or a :class:`~vi_jax.State`) for :func:`ensemble`: the named
    fields take per-member values (leading member axis) and every other array field is
    repeated per member, e.g. ``vary(model, mass=jnp.linspace(120, 130, 64))``."""
    names = {f.name for f in dataclasses.fields(tree)}
    if not fields:
        raise ValueError("fields: expected at least one field=values pair")
    counts = set()
    for key, value in fields.items():
        if key not in names:
            raise ValueError(f"{key}: not a field of {type(tree).__name__}; expected one of {sorted(names)}")
        old = getattr(tree, key)
        value = val.as_array(key, value)
        if old is None or value.shape[1:] != jnp.shape(old):
            raise ValueError(
                f"{key}: expected shape (members,) + {jnp.shape(old)}, got shape {value.shape}"
            )
        counts.add(value.shape[0])
    if len(counts) != 1:
        raise ValueError(f"fields: expected one member count for all fields, got {sorted(counts)}")
    (n,) = counts
    out = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)) if eqx.is_array(x) else x, tree)
    for key, value in fields.items():
        out = eqx.tree_at(lambda t, key=key: getattr(t, key), out, jnp.asarray(value, jnp.result_type(getattr(tree, key))))
    return out


def member_converged(sol: Solution):
    """Per member: True when every step's Newton solve succeeded."""
    return jnp.all(sol.result == SUCCESS, axis=-1)


def ensemble(
    system,
    x0: State,
    h,
    n_steps: int,
    *,
    system_axes=None,
    x0_axes=0,
    method: str = "auto",
    mesh=None,
    scheme: str = "dep",
    tau=None,
    order: int | None = None,
    save_every: int = 1,
    throw: bool = True,
    rtol=None,
    max_newton_iterations: int = 20,
    checkpoint: bool = True,
    progress: bool = False,
) -> Solution:
    """``vj.simulate`` for every member of an ensemble; fields get a leading member axis.

    ``system_axes`` / ``x0_axes``: 0 where the argument carries a leading member axis, None
    where it is shared, or a pytree prefix of such (as ``jax.vmap``); :func:`vary` builds
    batched arguments. ``method``: "batched" (the batched step generated from the scene's
    Lagrangian), "vmap" (``jax.vmap`` of the DEP program) or "auto"
    (batched). ``mesh``: a ``jax.sharding.Mesh``; members
    are split over all its devices (padded to a multiple of their number). The other keywords
    are ``vj.simulate``'s (``checkpoint=True`` by default, on every path: reverse mode
    rematerialises, memory grows with saved nodes, not steps; ``scheme="splitting"``:
    ``jax.vmap`` of the explicit splitting);
    ``throw=True`` raises :class:`~vi_jax.NewtonFailure` naming the failed members. On concrete
    inputs (no ``mesh``) the DEP paths take the step counts as traced integers: one compiled
    program per saved-node capacity (the power of two ≥ the saved nodes), not per ``n_steps``;
    through the generated step, a program without Newton's full iterations runs first and the
    full one only if some member needs them (:func:`optimistically`). Members
    whose energy error says their run is meaningless get one :class:`~vi_jax.AccuracyWarning`
    that counts them. On CPU a concrete call saving a node every 4 steps or more runs the
    members in one group per core (at least 64 members each), the groups at the same time; there
    the generated step is compiled with ``ENSEMBLE_OPTIONS`` (:mod:`._compile_options`).
    Where the scene's values are known when the step is traced (concrete inputs, or a scene a
    caller's ``jit`` closes over), the generated step folds its entries that are exactly zero for
    every member (``FOLD_ZEROS``): one program per pattern of zeros.
    ``progress=True`` (outside ``jit``) runs the members in equal groups of
    at least 64 (at most 100 groups; one compiled program) with a progress bar between them.
    """
    val.check_choice("method", method, METHODS)
    if scheme == "splitting" and method == "batched":
        raise ValueError("method: 'batched' is the DEP scheme's generated step; the splitting runs as 'vmap' or 'auto'")
    sys_axes = leaf_axes("system_axes", system, system_axes)
    state_axes = leaf_axes("x0_axes", x0, x0_axes)
    counts = {
        "system": member_counts("system_axes", system, sys_axes),
        "x0": member_counts("x0_axes", x0, state_axes),
    }
    sizes = set(counts["system"] + counts["x0"])
    if not sizes:
        raise ValueError("system_axes, x0_axes: expected at least one batched argument, got None for both")
    if len(sizes) > 1:
        raise ValueError(
            "x0_axes, system_axes: batched leaves must share one member count, got "
            + ", ".join(f"{k}: {sorted(set(v))}" for k, v in counts.items() if v)
        )
    (n_members,) = sizes
    if n_members < 1:
        raise ValueError("x0_axes, system_axes: expected at least one member, got 0")
    h, n_steps, save_every, tau_map, order = validate_scheme(  # every member's values below
        take_member(system, sys_axes, 0), take_member(x0, state_axes, 0), h, n_steps, save_every, scheme, tau, order, values=False
    )
    val.check_values(_named_values(system, x0, sys_axes, state_axes), system.group, x0.g, state_axes.g == 0)
    batched = None
    if scheme == "dep" and method != "vmap":
        batched = "generated"
    if mesh is not None and not isinstance(mesh, jax.sharding.Mesh):
        raise ValueError(f"mesh: expected a jax.sharding.Mesh, got {type(mesh).__name__}")

    dtype = jnp.result_type(x0.g, x0.xi, h)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    h = val.converted(h, dtype)
    options = dict(
        n_saved=n_steps // save_every, save_every=save_every, tau=tau_map, order=order,
        rtol=_default_rtol(dtype) if rtol is None else float(rtol),
        max_iterations=val.check_int("max_newton_iterations", max_newton_iterations, 1),
        checkpoint=bool(checkpoint), batched=batched, scheme=scheme,
        chunk=CHUNK if target_platform(mesh) == "cpu" else None,
        zeros=zero_entries(system, sys_axes) if batched == "generated" and FOLD_ZEROS else (),  # () for traced leaves
    )
    dynamic, static = eqx.partition((system, x0), eqx.is_array)
    axes = (sys_axes, state_axes)

    # Eager calls: the DEP step counts are traced, one program per saved-node capacity.
    concrete = val.is_eager((dynamic, h))
    looped = scheme == "dep" and concrete

    def run(dynamic, n_members):
        if looped:
            n_saved = options["n_saved"]
            counts = tuple(val.step_count(n) for n in (n_saved, save_every))
            loop_options = {k: options[k] for k in ("tau", "order", "rtol", "max_iterations", "batched", "chunk", "zeros")}
            loop_options["capacity"] = capacity = ensemble_capacity(n_saved)
            if mesh is None:
                def program(max_iterations, stop_at_failure):
                    plan = dict(loop_options, max_iterations=max_iterations, stop_at_failure=stop_at_failure)
                    loop = _run_loop if batched == "generated" else _vmap_loop
                    if options["chunk"] is None:  # an accelerator: the whole batch in every kernel
                        return loop(dynamic, static, axes, h, *counts, n_members=n_members, **plan)
                    return on_cores(loop, dynamic, axes, n_members, save_every, static, axes, h, *counts, **plan)

                if batched == "generated":  # vj.simulate's plan (figures: _any_failed)
                    sol = optimistically(program, options["max_iterations"], _any_failed)
                else:
                    sol = program(options["max_iterations"], False)
            else:
                sol = _run_sharded(dynamic, static, axes, h, mesh, n_members, loop_options, counts)
            return sol if capacity == n_saved else _first_nodes(sol, n_saved + 1)
        if mesh is None:
            return _run(dynamic, static, axes, h, n_members=n_members, **options)
        return _run_sharded(dynamic, static, axes, h, mesh, n_members, options)

    with full_precision():
        if progress and concrete:
            sol = _run_in_groups(run, dynamic, axes, n_members, n_steps)
        else:
            sol = run(dynamic, n_members)
    sol = _check_members(sol) if throw else sol
    warn_if_meaningless(sol.energy, "ensemble", members=True)
    return sol


@eqx.filter_jit
def _run(dynamic, static, axes, h, *, n_members, n_saved, save_every, tau, order, rtol, max_iterations, checkpoint, batched, scheme, chunk,
         zeros=()):
    system, x0 = eqx.combine(dynamic, static)
    if batched == "generated":
        rule, gammas = composition_coefficients(order)
        if chunk is not None:
            dynamic, h = _opaque(dynamic, h)

        def kernel(system, x0, n):
            return generated_scan(system, x0, h, axes, n_saved, save_every, tau, rule, gammas, rtol, max_iterations, n, checkpoint, chunk is not None,
                                  zeros)

        nodes = in_chunks(dynamic, static, axes, n_members, chunk, kernel)
        return generated_solution(eqx.combine(dynamic, static)[0], axes[0], nodes, h, save_every, rtol, max_iterations, chunk is not None)

    if scheme == "splitting":  # jitted pieces, cached as for single runs: no dots (see below)
        def split(system, x0):
            return simulate(system, x0, h, n_saved * save_every, scheme=scheme, order=order, save_every=save_every, throw=False, checkpoint=checkpoint)

        return eqx.filter_vmap(split, in_axes=axes, axis_size=n_members)(system, x0)
    rule, gammas = composition_coefficients(order)

    def one(system, x0):
        return scan_program(
            system, _cast(x0, h.dtype), h, n_saved, tau=tau, rule=rule, gammas=gammas, save_every=save_every,
            rtol=rtol, max_iter=max_iterations, checkpoint=checkpoint,
        )

    with batched_products(chunk is not None), keeping_dots():  # scan_program is traced afresh: no cached inner jit
        return eqx.filter_vmap(one, in_axes=axes, axis_size=n_members)(system, x0)


def _opaque(dynamic, h):
    """The generated step's inputs behind an optimisation barrier: under a caller's ``jit`` that
    closes over the scene and h, XLA would fold them into the program as constants, and with h
    constant it drops the step's fusion boundaries (conditionals on h == h): the heavy top ran
    2.2-2.3x and the rigid body 1.4-2.8x slower so (two runs of ``python
    benchmarks/closed_over_inputs.py``). The GPU plan gets no barrier: it
    has no fusion boundaries to keep: there the barrier only cost constant folding (H100, 2^20
    members closed over, 1.07-1.10x slower with it: ``python benchmarks/closed_over_inputs.py
    --members 1048576 --steps 238 --scenes heavy_top rigid_body [--order 2]``)."""
    return jax.lax.optimization_barrier((dynamic, h))


def _named_values(system, x0, sys_axes, state_axes):
    """(name, leaf, whether it carries the member axis) for x0's fields and the scene's float
    parameters, named as ``vj.simulate``'s checks name them."""
    is_none = lambda x: x is None  # noqa: E731
    fields = [(f"x0.{k}", getattr(x0, k), getattr(state_axes, k) == 0) for k in ("g", "xi", "q", "qdot") if getattr(x0, k) is not None]
    leaves = zip(jax.tree.leaves(system, is_leaf=is_none), jax.tree.leaves(sys_axes, is_leaf=is_none), strict=True)
    return fields + [("system parameters", leaf, ax == 0) for leaf, ax in leaves if val.is_numeric(leaf)]


def _cast(x0, dtype):
    return jax.tree.map(lambda x: jnp.asarray(x, dtype), x0)


@functools.partial(jax.jit, static_argnums=1)
def _first_nodes(sol, n):
    """The first ``n`` nodes of every member, sliced on the device (an ensemble's rows can be
    gigabytes: no trip through the host, at a small compile per new ``n``)."""
    return jax.tree.map(lambda x: x[:, :n], sol)


def optimistically(program, max_iterations, failed):
    """``program(max_iterations, stop_at_failure)`` (a concrete run's looped program) first
    without Newton's full iterations, stopping at the first failed node, then, only if
    ``failed(solution)``, with them (the generated step: its first call compiles 0.71–0.78× as
    long where no member needs them, ``python benchmarks/ensemble_first_call.py``)."""
    common = 1 + CHORD_ITERATIONS
    if max_iterations <= common:
        return program(max_iterations, False)
    sol = program(common, True)
    return program(max_iterations, False) if failed(sol) else sol


def ensemble_capacity(n_saved: int) -> int:
    """Saved-node rows of the looped program: the power of two ≥ ``n_saved`` (a buffer per
    member: no minimum like ``vj.simulate``'s 1024)."""
    return 1 << max(n_saved - 1, 0).bit_length()


@jax.jit
def _any_failed(sol):
    """Whether some member's step failed, reduced on the device (a GPU ensemble's result codes
    can be over 100 MB: no trip through the host). ``python benchmarks/ensemble_first_call.py``
    (order 2, 64 members): the optimistic plan's first call took 0.68x (vehicle) and 0.75x (heavy
    top, h = 0.01) the full program's alone; a run that needs the full iterations pays both
    programs (heavy top, h = 0.02: 1.82x)."""
    return jnp.any(sol.result != SUCCESS)


def _run_loop(dynamic, static, axes, h, n_saved, save_every, *, n_members, capacity, tau, order, rtol, max_iterations, batched, chunk,
              stop_at_failure=False, zeros=()):
    """``_run``'s DEP paths with traced ``n_saved`` (≤ ``capacity``) and ``save_every``;
    ``stop_at_failure`` and ``zeros`` (the generated step only): :func:`loop_member_nodes`,
    :func:`~._generated_step.zero_entries`."""
    rule, gammas = composition_coefficients(order)
    if batched == "generated":
        if chunk is not None:
            dynamic, h = _opaque(dynamic, h)

        def kernel(system, x0, n):
            return generated_loop(system, x0, h, axes, n_saved, save_every, capacity, tau, rule, gammas, rtol, max_iterations, n, chunk is not None,
                                  stop_at_failure, zeros)

        nodes = in_chunks(dynamic, static, axes, n_members, chunk, kernel)
        return generated_solution(eqx.combine(dynamic, static)[0], axes[0], nodes, h, save_every, rtol, max_iterations, chunk is not None)

    def one(system, x0):
        return loop_program(
            system, _cast(x0, h.dtype), h, n_saved, save_every, capacity=capacity, tau=tau, rule=rule, gammas=gammas,
            rtol=rtol, max_iter=max_iterations,
        )

    with batched_products(chunk is not None), keeping_dots():
        return eqx.filter_vmap(one, in_axes=axes, axis_size=n_members)(*eqx.combine(dynamic, static))


# The generated step's CPU programs get ENSEMBLE_OPTIONS (figures there; nested in _sharded or on
# an accelerator, none). The vmap path's do not: its dots and reductions vectorised 512 bits wide
# round differently.
_vmap_loop = eqx.filter_jit(_run_loop)
_run_loop = cpu_options_jit(_run_loop, ENSEMBLE_OPTIONS)


def _run_sharded(dynamic, static, axes, h, mesh, n_members, options, counts=()):
    """Pad the members to a multiple of the devices, split them over ``mesh`` and run each
    share independently (``jax.shard_map``: no communication between devices); with traced
    ``counts`` (n_saved, save_every) each share runs ``_run_loop``, else ``_run``."""
    n_dev = mesh.devices.size
    padded = -(-n_members // n_dev) * n_dev
    spec = PartitionSpec(mesh.axis_names)
    is_none = lambda x: x is None  # noqa: E731

    def pad(ax, x):
        return x if ax is None or x is None else pad_members(x, padded)

    dynamic = jax.tree.map(pad, axes, dynamic, is_leaf=is_none)
    in_specs = jax.tree.map(lambda ax, x: None if x is None else (PartitionSpec() if ax is None else spec), axes, dynamic, is_leaf=is_none)
    place = lambda ps, x: jax.device_put(x, NamedSharding(mesh, ps))  # noqa: E731
    dynamic = jax.tree.map(place, in_specs, dynamic, is_leaf=lambda x: isinstance(x, PartitionSpec))
    counts = tuple(place(PartitionSpec(), c) for c in counts)
    program = _sharded if options["batched"] == "generated" else _sharded_vmap
    sol = program(
        dynamic, place(PartitionSpec(), h), counts, static=static, axes=axes, mesh=mesh, in_specs=in_specs, n_local=padded // n_dev, **options
    )
    if padded == n_members:
        return sol
    return jax.tree.map(lambda x: place(PartitionSpec(), x)[:n_members], sol)


def _sharded(dynamic, h, counts, *, static, axes, mesh, in_specs, n_local, **options):
    def local(dynamic, h, counts):
        if counts:
            return _run_loop(dynamic, static, axes, h, *counts, n_members=n_local, **options)
        return _run(dynamic, static, axes, h, n_members=n_local, **options)

    spec = PartitionSpec(mesh.axis_names)
    in_specs = (in_specs, PartitionSpec(), tuple(PartitionSpec() for _ in counts))
    return jax.shard_map(local, mesh=mesh, in_specs=in_specs, out_specs=spec, check_vma=False)(dynamic, h, counts)


_sharded_vmap = eqx.filter_jit(_sharded)
_sharded = cpu_options_jit(_sharded, ENSEMBLE_OPTIONS)  # as _run_loop


def _run_in_groups(run, dynamic, axes, n_members, n_steps):
    """``run`` over equal groups of members (at most 100, of at least ``MIN_GROUP``: one
    program), one after another, with a tqdm bar counting member-steps; the groups' results
    joined."""
    from tqdm.auto import tqdm

    size = -(-n_members // max(1, min(100, n_members // MIN_GROUP)))
    parts = []
    with tqdm(total=n_members * n_steps, unit="member-step", unit_scale=True, desc="ensemble") as bar:
        for start in range(0, n_members, size):
            parts.append(jax.tree.map(np.asarray, run(member_group(dynamic, axes, start, size), size)))  # to the host as it comes
            bar.update(min(size, n_members - start) * n_steps)
    return join_groups(parts, n_members)


def _check_members(sol: Solution) -> Solution:
    failed = jnp.any(sol.result != SUCCESS, axis=-1)
    if val.is_concrete(failed):
        bad = np.flatnonzero(np.asarray(failed))
        if bad.size:
            k = bad[0]
            node = int(np.argmax(np.asarray(sol.result[k]) != SUCCESS))
            code = int(sol.result[k, node])
            raise NewtonFailure(
                f"{bad.size} of {failed.shape[0]} members failed (members {bad[:10].tolist()}"
                f"{' …' if bad.size > 10 else ''}); member {k} at saved node {node} (t ≈ {float(sol.t[k, node]):.6g}): "
                f"{RESULT_MESSAGES.get(code, code)}. Reduce h, raise max_newton_iterations, or pass throw=False "
                "and inspect member_converged(sol)."
            )
        return sol
    return eqx.error_if(sol, jnp.any(failed), "ensemble: a member's DEP step failed; pass throw=False and inspect member_converged(sol)")
