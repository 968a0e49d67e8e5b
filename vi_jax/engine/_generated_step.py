"""The batched DEP step of any scene, generated from its reduced Lagrangian: ``vj.ensemble``'s
fast path (every group, τ = Cayley or exp, orders 1/2/4/6, with or without advected
parameters and additional dynamics).

The step is ``vj.simulate``'s (:func:`vi_jax.discrete.dep_step`, seed 000 eq. 42 with 43–44),
cut into per-member pieces — the body configuration and advected parameter, the F⁻ residual
and its forward-mode Jacobian, the F⁺ update — each run on component arrays
(:func:`componentwise`): every array of a piece is held as its components, arrays over the
members, so XLA fuses a whole Newton iteration into one loop over the members. Newton itself
(:func:`newton_members`) runs on those tuples with the iteration of ``vj.simulate``: one
Newton step, two chord steps, a check, masked fallback iterations while a member has not
converged, a final correction, implicit-function gradients; on the CPU plan, where the
Jacobian costs most, the first step may be a chord step on factors carried from an earlier step
(:func:`make_step`, :func:`~._member_newton.next_periods`), and where the residual costs most,
each chord step runs only while some member has not converged, by those members alone (each
stops at its first converged iterate, as ``vj.simulate``'s rolled loop); a concrete call's program
with Newton's full iterations, where both apply, rolls its iterations into one loop
(``ROLL_FULL_ITERATIONS``). On the CPU plan a single-stage step
(orders 1, 2) starts Newton from the extrapolation 2ξ_k − ξ_{k−1}, as ``vj.simulate`` does
(:func:`_extrapolated`); the accelerator plan starts from ξ_k and runs the step speculatively
(:func:`_speculative`). On the CPU plan the member loops are one kernel
(:func:`~vi_jax._one_kernel.one_kernel`: no dispatch per fused operation, whatever XLA's flags).
A failed step turns the member's state to NaN, as ``vj.simulate`` does.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..discrete._composition import composition_coefficients
from ..discrete._dep import StepState, StepStats, _split, discrete_momenta, legendre_initial_state
from ..solvers import CHORD_ITERATIONS, SINGULAR_DIFFERENCE_MAP, SUCCESS
from ._advance import extrapolation, no_previous
from ._explicit_unknowns import dep_residual
from ._simulate import assemble
from ..lie import difference_map
from ..lie._small import batched_products
from ._components import componentwise, components, from_member_arrays, member_arrays
from .._one_kernel import one_kernel
from ._member_loops import loop_member_nodes, scan_member_nodes
from ._member_newton import MAX_PERIOD, fusion_boundary, lu, newton_members, next_periods, on_member_tuples, value_and_jacobian_of


def _pieces(static, tau, rule):
    """The per-member pieces of one step, each a function of the scene's array leaves first."""

    def scene(params):
        return eqx.combine(params, static)

    def body(params, g, q):
        system = scene(params)
        return system.body_configuration(g, q), system.body_advected(g)

    residual = dep_residual(static, tau, rule)

    def update(params, h, z, g, q, n, a):
        system = scene(params)
        G = system.group
        xi, nu = _split(system, z)
        _, (m_next, p_next), _ = discrete_momenta(system, tau, rule, h, z, n, a)
        q_next = None if q is None else q + h * system.configuration_action.act(g, nu)
        return G.compose(g, tau.tau(G, h * xi)), q_next, m_next, p_next, tau.is_regular(G, h * xi)

    return body, residual, value_and_jacobian_of(residual, 2), update


FIELDS = ("g", "q", "M", "P", "z")
# Newton's factors carried from step to step (make_step): None carries them where the residual
# with its Jacobian costs at least CARRY_COST residuals (scene_operations), True / False everywhere /
# nowhere (the benchmark's switch). python benchmarks/carried_factors.py: 1.84x faster on the
# vehicle at order 2 and 1.78x at order 4 (cost 5.1); 0.84-0.96x on the heavy top (3.4, 2.2),
# the rigid body and the vehicle at order 1 (2.1), whose Jacobian costs less than carrying.
CARRY_FACTORS = None
CARRY_COST = 4
# Newton's chord steps checked (make_step, newton_members' checked_chords): None checks them
# where the residual costs at least CHECK_COST operations per member (scene_operations),
# True / False everywhere / nowhere (the benchmark's switch). A checked chord step is skipped
# when every member of the chunk has converged, and masked per member otherwise: the masks cost
# about 10 operations a member whether or not a step is skipped. python
# benchmarks/checked_chords.py: 1.2x faster on the vehicle at orders 1 and 2, whose Newton step
# mostly converges; 0.87x on the heavy top at order 1 (134 operations), whose members take both
# chord steps at h = 0.01, 0.96x at order 2 (453); the rigid body (92, 152) 1.0x.
CHECK_CHORDS = None
CHECK_COST = 200
# Newton's first guess in single-stage steps: the extrapolation 2ξ_k − ξ_{k−1} (True) or ξ_k
# (False, the benchmark's switch): _extrapolated.
PREDICT = True
# The accelerator plan (python benchmarks/gpu_step_profile.py, H200, 2^20 members): the
# speculative step (_speculative; False: the fallback inside the step), two steps per iteration
# of the step loop (ACCELERATOR_UNROLL: a step's result then needs no copy into the loop's
# carry), and Newton from ξ_k (PREDICT_ON_ACCELERATORS). The vehicle at order 1 ran 1.53x /
# 2.39x faster (float64 / float32) than with the plan before (the fallback inside the step,
# the extrapolation) and 1.77x / 2.52x faster than this plan with the extrapolation.
SPECULATIVE = True
ACCELERATOR_UNROLL = 2
PREDICT_ON_ACCELERATORS = False
# A concrete call's full program (run where some member needs Newton's full iterations) with
# carried factors and checked chord steps: its iterations rolled into one loop (True) or
# unrolled (False, the benchmark's switch): generated_loop. python
# benchmarks/rolled_full_iterations.py.
ROLL_FULL_ITERATIONS = True


class _Layout(eqx.Module):
    """Shapes of the state's fields: carries are flat tuples of member arrays."""

    shapes: tuple = eqx.field(static=True)

    def flat(self, state, n_members, dtype):
        return tuple(() if x is None else member_arrays(x, n_members, dtype) for x in state)

    def unflat(self, carry):
        return tuple(None if s is None else from_member_arrays(c, s) for c, s in zip(carry, self.shapes))


def _nan_where(failed, carry):
    return jax.tree.map(lambda x: jnp.where(failed, jnp.nan, x), carry)


def _equations_of(static, params, tau, rule, n_members, layout, boundaries):
    """``equations(carry, h)``: the step's configuration pieces, its boundary, and its residual
    and Jacobian as functions of the unknowns' member arrays; and the update."""
    body, residual, value_and_jacobian, update = (componentwise(f, n_members) for f in _pieces(static, tau, rule))

    def equations(carry, h):
        dtype = carry[2][0].dtype
        g, q, M, P, z = layout.unflat(carry)
        hc = components(h, False)
        n, a = body(params, g, q)
        target = M if P is None else np.concatenate([M, P])
        always = h == h  # True unless h is NaN (and then every value is)
        boundary = (lambda tree: fusion_boundary(tree, always)) if boundaries else (lambda tree: tree)
        fn, fn_jac = on_member_tuples(
            lambda z: residual(params, hc, z, n, a, target, boundary=boundary),
            lambda z: value_and_jacobian(params, hc, z, n, a, target, boundary=boundary),
            z.shape, n_members, dtype, boundary,
        )
        return (g, q, z, n, a, hc), boundary, fn, fn_jac

    return equations, update


def _member_operations(jaxpr, n_members):
    """Equations of a jaxpr (and of the jaxprs in its equations) with a member array as output."""
    count = 0
    for eqn in jaxpr.eqns:
        count += sum(_member_operations(sub, n_members) for sub in jax.extend.core.jaxprs_in_params(eqn.params))
        count += any(getattr(v.aval, "shape", None) == (n_members,) for v in eqn.outvars)
    return count


def _residual_operations(static, params, tau, rule, n_members, layout, carry, h):
    """Operations per member in the jaxprs of the residual and of the residual with its Jacobian."""
    equations, _ = _equations_of(static, params, tau, rule, n_members, layout, False)
    _, _, fn, fn_jac = equations(carry, h)
    return tuple(_member_operations(jax.make_jaxpr(f)(carry[4]).jaxpr, n_members) for f in (fn, fn_jac))


def scene_operations(system, x0, h, tau="cayley", order=1, system_axes=None, folded=False):
    """Operations per member in the jaxprs of the residual and of the residual with its Jacobian
    (what ``CHECK_COST`` and ``CARRY_COST`` measure) for an ensemble of ``x0`` (members first)
    under ``system`` (``system_axes``: 0 for a member axis on every leaf); ``folded``: with the
    scene's zeros folded (:func:`zero_entries`)."""
    n_members = jax.tree.leaves(x0)[0].shape[0]
    axes = (jax.tree.map(lambda _: system_axes, system), jax.tree.map(lambda _: 0, x0))
    zeros = zero_entries(system, axes[0]) if folded else ()
    params, static, _, layout, carry = _start(system, x0, axes, jnp.asarray(h).dtype, n_members, zeros)
    rule, _ = composition_coefficients(order)
    return _residual_operations(static, params, difference_map(tau), rule, n_members, layout, carry, jnp.asarray(h))


def make_step(static, params, tau, rule, rtol, max_iterations, n_members, layout, boundaries=True, carry_factors=False,
              check_chords=False, rolled=False):
    """``step((carry, extra), h) -> ((carry, extra), (iterations, residual, result))`` on flat
    member arrays; ``boundaries``: the fusion boundaries of :func:`~._member_newton.fusion_boundary` at the residuals,
    the Jacobian and the values the step marks as shared (the CPU plan; a GPU fuses without
    them and would pay a conditional per boundary). ``carry_factors``: ``extra`` holds each
    member's LU factors, refresh period and its ceiling, and the step count (:func:`next_periods`); else ``()``
    and every step takes a fresh Jacobian. ``check_chords`` (with ``boundaries``): each chord
    step only while some member has not converged (``newton_members``' ``checked_chords``).
    ``rolled``: with both, Newton's full iterations and the chord steps rolled into one loop
    where the full iterations are compiled (``newton_members``' ``rolled``).
    ``step.start(carry)`` is the first ``extra``."""
    equations, update = _equations_of(static, params, tau, rule, n_members, layout, boundaries)

    def start(carry):
        """Factors of the identity with period 2 (ceiling ``MAX_PERIOD``): every member takes a
        Jacobian at step 0 and tries it at step 1."""
        if not carry_factors:
            return ()
        z = carry[4]
        eye = [[jnp.ones_like(z[0]) if i == j else jnp.zeros_like(z[0]) for j in range(len(z))] for i in range(len(z))]
        periods = (jnp.full((n_members,), 2, jnp.int32), jnp.full((n_members,), MAX_PERIOD, jnp.int32))
        return lu(eye), periods, jnp.asarray(0, jnp.int32)

    def step(state, h):
        carry, extra = state
        dtype = carry[2][0].dtype
        (g, q, z, n, a, hc), boundary, fn, fn_jac = equations(carry, h)
        checked = boundary if boundaries and check_chords else None
        options = dict(rtol=rtol, max_iterations=max_iterations, value_and_jacobian=fn_jac, checked_chords=checked, rolled=rolled)
        if carry_factors:
            factors, (period, ceiling), count = extra
            refresh = count % period == 0
            zt, (iterations, rel, result), (factors, early, fell_back) = newton_members(
                fn, carry[4], factors=factors, refresh=refresh, **options
            )
            extra = (factors, next_periods(period, ceiling, refresh, early, fell_back), count + 1)
        else:
            zt, (iterations, rel, result) = newton_members(fn, carry[4], **options)
        z = from_member_arrays(zt, z.shape)
        g, q, M, P, regular = update(params, hc, z, g, q, n, a, boundary=boundary)
        result = jnp.where(regular[()], result, jnp.int8(SINGULAR_DIFFERENCE_MAP))
        new = layout.flat((g, q, M, P, z), n_members, dtype)
        (failed,) = boundary([result != SUCCESS])  # read by every component of the state
        return (_nan_where(failed, new), extra), (iterations, rel, result)

    step.start = start
    return step


def zero_entries(system, sys_axes):
    """Per array leaf of a concrete ``system`` (in the order of its leaves): the flat indices of
    the entries that are exactly zero for every member (``sys_axes``: 0 for a leaf with a
    leading member axis); ``()`` for a traced leaf. The generated step folds them (:func:`_start`)
    where the scene is known when it is traced (``vj.ensemble``'s ``FOLD_ZEROS``)."""
    is_none = lambda x: x is None  # noqa: E731
    out = []
    for ax, x in zip(jax.tree.leaves(sys_axes, is_leaf=is_none), jax.tree.leaves(system, is_leaf=is_none)):
        if not eqx.is_array(x):
            continue
        if isinstance(x, jax.core.Tracer):
            out.append(())
            continue
        if ax == 0 and isinstance(x, jax.Array) and x.size >= LARGE_LEAF:
            zero = np.asarray(_zero_for_every_member(x))
        else:
            v = np.asarray(x)
            zero = np.all(v.reshape((v.shape[0] if ax == 0 else 1, -1)) == 0, axis=0)
        out.append(tuple(int(i) for i in np.flatnonzero(zero)))
    return tuple(out)


# A member-axis leaf of at least this many entries is reduced by zero_entries on its device (a
# GPU's leaf would otherwise cross to the host whole). On the CPU, a vehicle with a mass per member (vj.vary: every
# leaf per member), 10^6 members: 57 ms on the host, 12 ms so (a throwaway timing).
LARGE_LEAF = 1 << 20


@jax.jit
def _zero_for_every_member(x):
    return jnp.all(x.reshape(x.shape[0], -1) == 0, axis=0)


def _is_components(x):
    """Whether ``x`` is a scene leaf held as components (an object array)."""
    return isinstance(x, np.ndarray) and x.dtype == object


def _with_zeros(params, zeros):
    """``params`` (leaves as components) with the entries ``zeros`` (:func:`zero_entries`) the
    constant 0: products with them fold away at trace time, as the zeros of structure matrices
    do (a diagonal inertia's off-diagonal entries)."""
    leaves, treedef = jax.tree.flatten(params, is_leaf=_is_components)
    if len(leaves) != len(zeros):
        raise ValueError(f"zeros: expected one tuple of indices per array leaf of the scene ({len(leaves)}), got {len(zeros)}")
    folded = []
    for x, indices in zip(leaves, zeros):
        if indices:
            x = x.copy()
            flat = x.reshape(-1)
            for i in indices:
                flat[i] = np.zeros((), jnp.result_type(flat[i]))[()]
        folded.append(x)
    return jax.tree.unflatten(treedef, folded)


def _start(system, x0, axes, dtype, n_members, zeros=()):
    """Scene leaves as components (the entries ``zeros``, :func:`zero_entries`, as constant
    zeros), the initial state (members first) and the carry layout."""
    sys_axes, state_axes = axes
    state0 = jax.vmap(
        lambda s, x: legendre_initial_state(s, x.g, x.xi, x.q, x.qdot), in_axes=(sys_axes, state_axes), axis_size=n_members
    )(system, x0)
    state0 = jax.tree.map(lambda x: jnp.asarray(x, dtype), state0)
    params, static = eqx.partition(system, eqx.is_array)
    params = jax.tree.map(lambda ax, x: None if x is None else components(x, ax == 0), sys_axes, params, is_leaf=lambda x: x is None)
    if any(zeros):
        params = _with_zeros(params, zeros)
    fields = tuple(getattr(state0, f) for f in FIELDS)
    layout = _Layout(tuple(None if x is None else x.shape[1:] for x in fields))
    carry0 = layout.flat(tuple(None if x is None else components(x, True) for x in fields), n_members, dtype)
    return params, static, state0, layout, carry0


def _one_step(step, gammas, h):
    """One (composed) step; its statistics are the worst over the sub-steps. With carried
    factors each sub-step (its own h) keeps its own factors and periods; the step count is the
    composed step's."""
    if len(gammas) == 1:
        return lambda state: step(state, gammas[0] * h)
    hs = jnp.asarray(gammas, h.dtype) * h

    def composed(state):
        carry, extra = state
        if extra == ():
            def sub(carry, h_i):
                (carry, _), stats = step((carry, ()), h_i)
                return carry, ((), stats)

            xs = hs
        else:
            factors, periods, count = extra

            def sub(carry, xs):
                h_i, factors, periods = xs
                (carry, (factors, periods, _)), stats = step((carry, (factors, periods, count)), h_i)
                return carry, ((factors, periods), stats)

            xs = (hs, factors, periods)
        carry, (kept, stats) = jax.lax.scan(sub, carry, xs)
        extra = () if extra == () else kept + (count + 1,)
        return (carry, extra), jax.tree.map(lambda x: jnp.max(x, axis=0), stats)

    return composed


def _extrapolated(one_step):
    """``one_step`` with Newton started from 2ξ_k − ξ_{k−1} (error O(h²)) instead of ξ_k (O(h));
    the state carries ξ_{k−1} beside ``extra`` (:func:`~._advance.extrapolation`, as
    ``vj.simulate``). ``python benchmarks/extrapolated_guess.py``: the heavy top at h = 0.01
    took Newton's fallback iterations in 39% of its member-steps from ξ_k and in none so (1.28x
    / 1.32x faster at orders 1 / 2; 1.44x at h = 0.02, 79% → 18%); 0.95-1.04x where no step
    fell back (the rigid body, the heavy top at h = 0.005, the vehicle at order 2), two runs."""

    def step(state):
        carry, (extra, z_prev) = state
        guess, after = extrapolation(carry[4], z_prev)
        (new, extra), stats = one_step((carry[:4] + (guess,), extra))
        return (new, (extra, after(new[4]))), stats

    return step


def _speculative(one_step_of, params, h, max_iterations):
    """The accelerator plan's step: every member's step without Newton's fallback iterations,
    then, only if a member did not succeed so, the whole step again with them (the same values
    either way): on a GPU the common path needs nothing of Newton's iterations kept in memory
    for the fallback (the step's inputs are), and a loop run zero or one times updates its
    result in place, where a conditional would copy the state (``python
    benchmarks/gpu_step_profile.py``). Differentiated as the step with the fallback inside
    (a loop of traced length has no reverse mode); the scene's parameters and h are explicit
    inputs of the rule."""
    leaves, treedef = jax.tree.flatten(params, is_leaf=_is_components)
    shapes = [x.shape if _is_components(x) else None for x in leaves]
    flat = [list(x.reshape(-1)) if _is_components(x) else x for x in leaves]

    def rebuild(flat):
        return jax.tree.unflatten(treedef, [x if s is None else from_member_arrays(x, s) for x, s in zip(flat, shapes)])

    def full(state, flat, h):
        return one_step_of(rebuild(flat), h, max_iterations)[0](state)

    @jax.custom_jvp
    def step(state, flat, h):
        new, stats = one_step_of(rebuild(flat), h, 1 + CHORD_ITERATIONS)[0](state)
        failed = jnp.any(stats[2] != SUCCESS)
        rerun = lambda c: (jnp.zeros_like(failed),) + full(state, flat, h)  # noqa: E731
        _, new, stats = jax.lax.while_loop(lambda c: c[0], rerun, (failed, new, stats))
        return new, stats

    step.defjvp(lambda primals, tangents: jax.jvp(full, primals, tangents))
    return lambda state: step(state, flat, h)


def _per_sub_step(extra, gammas):
    """The first ``extra`` of a composed step: factors and periods for each sub-step."""
    if extra == () or len(gammas) == 1:
        return extra
    factors, periods, count = extra
    stack = lambda x: jnp.broadcast_to(x, (len(gammas),) + jnp.shape(x))  # noqa: E731
    return jax.tree.map(stack, factors), jax.tree.map(stack, periods), count


def _setup(system, x0, h, axes, tau, rule, gammas, rtol, max_iterations, n_members, boundaries, rolled=False, zeros=()):
    dtype = jnp.asarray(h).dtype
    params, static, state0, layout, carry0 = _start(system, x0, axes, dtype, n_members, zeros)
    # Measured on the CPU plan only: a GPU's whole batch would take a Jacobian whenever one
    # member does.
    costs = _residual_operations(static, params, tau, rule, n_members, layout, carry0, h) if boundaries else (0, 0)
    carried = boundaries and costs[1] >= CARRY_COST * costs[0] if CARRY_FACTORS is None else CARRY_FACTORS
    checked = boundaries and costs[0] >= CHECK_COST if CHECK_CHORDS is None else CHECK_CHORDS
    predict = (PREDICT if boundaries else PREDICT_ON_ACCELERATORS) and len(gammas) == 1

    def one_step_of(params, h, max_iterations):
        step = make_step(static, params, tau, rule, rtol, max_iterations, n_members, layout, boundaries, carried, checked, rolled)
        one_step = _one_step(step, gammas, h)
        return (_extrapolated(one_step) if predict else one_step), step.start

    one_step, start = one_step_of(params, h, max_iterations)
    if SPECULATIVE and not boundaries and not carried and max_iterations > 1 + CHORD_ITERATIONS:
        one_step = _speculative(one_step_of, params, h, max_iterations)
    carry0 = (carry0, _per_sub_step(start(carry0), gammas))
    if predict:
        carry0 = (carry0[0], (carry0[1], no_previous(carry0[0][4])))

    def worst_step(carry, _):
        carry, worst = carry
        carry, stats = one_step(carry)
        return (carry, jax.tree.map(jnp.maximum, worst, stats)), None

    return dtype, state0, layout, carry0, worst_step


def generated_scan(system, x0, h, axes, n_saved, save_every, tau, rule, gammas, rtol, max_iterations, n_members, checkpoint, boundaries=True,
                   zeros=()):
    """(initial state, (saved states, statistics)) of every member, members first, with static
    step counts; ``checkpoint`` rematerialises in reverse mode as ``vj.simulate`` does; the
    scene's entries ``zeros`` (:func:`zero_entries`) folded."""
    dtype, state0, layout, carry0, worst_step = _setup(system, x0, h, axes, tau, rule, gammas, rtol, max_iterations, n_members, boundaries,
                                                       zeros=zeros)
    unroll = 1 if boundaries else ACCELERATOR_UNROLL
    loops = lambda carry0: scan_member_nodes(worst_step, carry0, _saved, n_saved, save_every, checkpoint, n_members, dtype, unroll)  # noqa: E731
    saved, stats = (one_kernel(loops) if boundaries else loops)(carry0)
    return state0, _unpack(layout, carry0[0], saved, stats)


def generated_loop(system, x0, h, axes, n_saved, save_every, capacity, tau, rule, gammas, rtol, max_iterations, n_members, boundaries=True,
                   stop_at_failure=False, zeros=()):
    """The same with traced ``n_saved`` (≤ ``capacity``) and ``save_every``: one program for every
    run length (``stop_at_failure``: :func:`loop_member_nodes`; ``zeros``: :func:`zero_entries`). A concrete call's program: with
    carried factors and checked chord steps, its Newton iterations are rolled where the full
    iterations are compiled (``newton_members``' ``rolled``: that program runs only where some
    member needs them; with the program without them, a user ``vj.System`` on SO(3) compiled for
    14.5 s instead of 19.8 at order 2 and 25.2 s instead of 30.7 at order 4, 1024 members:
    ``python benchmarks/rolled_full_iterations.py``)."""
    dtype, state0, layout, carry0, worst_step = _setup(system, x0, h, axes, tau, rule, gammas, rtol, max_iterations, n_members, boundaries,
                                                       rolled=ROLL_FULL_ITERATIONS, zeros=zeros)
    loops = lambda carry0: loop_member_nodes(worst_step, carry0, _saved, n_saved, save_every, capacity, n_members, dtype, stop_at_failure)  # noqa: E731
    saved, stats = (one_kernel(loops) if boundaries else loops)(carry0)
    return state0, _unpack(layout, carry0[0], saved, stats)


def _saved(state):
    """The member arrays a node saves: the carry, not the step's factors."""
    return jax.tree.leaves(state[0])


def _unpack(layout, carry0, saved, stats):
    """Packed rows (nodes, components, members) → the saved ``StepState`` and ``StepStats``
    with members first."""
    rows = list(jnp.transpose(saved, (1, 2, 0)))  # components × (members, nodes)
    fields = []
    for carry, shape in zip(carry0, layout.shapes):
        if shape is None:
            fields.append(None)
            continue
        size = int(np.prod(shape))
        part, rows = rows[:size], rows[size:]
        fields.append(jnp.stack(part, axis=-1).reshape(part[0].shape + shape))
    iterations, rel, result = (x.T.astype(t) for x, t in zip(jnp.moveaxis(stats, 1, 0), (jnp.int32, saved.dtype, jnp.int8)))
    return StepState(*fields), StepStats(iterations, rel, result)


def generated_solution(system, system_axes, nodes, h, save_every, rtol, max_iterations, dots):
    """The Solution of every member from the generated step's saved nodes (members first): the
    node diagnostics of ``vj.simulate`` under ``vmap``."""
    state0, (saved, stats) = nodes

    def one(system, state0, saved, stats):
        return assemble(system, state0, saved, stats, h, save_every, rtol, max_iterations)

    with batched_products(dots):
        return eqx.filter_vmap(one, in_axes=(system_axes, 0, 0, 0))(system, state0, saved, stats)
