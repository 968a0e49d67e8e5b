"""Newton's method for every member of an ensemble at once, on component arrays: the unknowns
are a tuple of arrays over the members, nothing couples two members. The iteration is
``vj.simulate``'s (:func:`vi_jax.solvers.newton_root`): one Newton step, chord steps, a check,
masked fallback Newton steps while some member has not converged, a final correction;
implicit-function gradients through ``jax.lax.custom_root`` (``implicit_root``).

Carried factors (the generated step, one step after another): the first Newton step may use
the LU factors of an earlier step's Jacobian instead of a fresh one — chord steps from the
start — for the members whose refresh schedule (:func:`next_periods`) says so. On the
vehicle at order 2 the Jacobian is over half of a step's operations (``python
benchmarks/generated_step_hlo.py``); the solution is converged to the same tolerance either way.

Unknowns with explicit equations (:func:`explicit_block`): rows of the Jacobian affine in as
many unknowns, with coefficients that do not depend on the unknowns (shared by all members, or
per member and independent of them, read from the Jacobian's jaxpr), are solved exactly first;
Newton runs on the other unknowns with those fixed (the vehicle's ν at order 1, seed 000
eq. 74, leaving ω to Newton as in eq. 73: ``python benchmarks/explicit_block.py``).

The Jacobian's entries may be known constants or scalars shared by all members (the generated
step's forward-mode Jacobian keeps them so: e.g. ∂P/∂ξ = 0 and ∂P/∂ν = M for a separable
scene); the unrolled LU below folds them, so only the entries that differ per member cost
work per member.
"""

import jax
import jax.numpy as jnp

from ..solvers import CHORD_ITERATIONS, MAX_ITERATIONS, NONFINITE, SUCCESS
from ..solvers._newton import implicit_root
from ._components import fold_mul, fold_sub, from_member_arrays, member_arrays


def vmax(v):
    out = v[0]
    for x in v[1:]:
        out = jnp.maximum(out, x)
    return out


def lu(A):
    """Unrolled LU factors of a small k×k matrix, without pivoting (as ``dense_solve``: the
    Newton matrices are h-perturbations of a positive definite Hessian)."""
    rows = [list(row) for row in A]
    k = len(rows)
    inv_diag, multipliers = [], []
    for j in range(k):
        inv_diag.append(1 / rows[j][j])
        col = []
        for i in range(j + 1, k):
            f = fold_mul(rows[i][j], inv_diag[j])
            rows[i] = [fold_sub(rows[i][c], fold_mul(f, rows[j][c])) for c in range(k)]
            col.append(f)
        multipliers.append(col)
    return rows, inv_diag, multipliers


def lu_solve(factors, b):
    rows, inv_diag, multipliers = factors
    k = len(b)
    y = list(b)
    for j in range(k):
        for f, i in zip(multipliers[j], range(j + 1, k)):
            y[i] = fold_sub(y[i], fold_mul(f, y[j]))
    x = [None] * k
    for i in reversed(range(k)):
        acc = y[i]
        for c in range(i + 1, k):
            acc = fold_sub(acc, fold_mul(rows[i][c], x[c]))
        x[i] = fold_mul(acc, inv_diag[i])
    return tuple(x)


def columns(linear, like):
    """Per-member Jacobian of a map with no coupling between members: column j is the map
    applied to the tangent with component j = 1 for every member."""
    k = len(like)
    cols = [linear(tuple(jnp.ones_like(c) if i == j else jnp.zeros_like(c) for i, c in enumerate(like))) for j in range(k)]
    return [[cols[j][i] for j in range(k)] for i in range(k)]


def value_and_jacobian_of(residual, argnum):
    """``residual(*args) -> (r, scale)`` ↦ ``(*args) -> (r, scale, ∂r/∂args[argnum])``, the
    Jacobian by forward mode (a per-member function, to run on components)."""

    def value_and_jacobian(*args):
        def with_aux(z):
            r, scale = residual(*args[:argnum], z, *args[argnum + 1 :])
            return r, (r, scale)

        jac, (r, scale) = jax.jacfwd(with_aux, has_aux=True)(args[argnum])
        return r, scale, jac

    return value_and_jacobian


def on_member_tuples(residual, value_and_jacobian, shape, n_members, dtype, boundary=lambda tree: tree):
    """:func:`newton_members`'s ``fn`` and ``value_and_jacobian`` from functions of the unknowns
    as components (an object array of ``shape``). Jacobian entries that are constants or shared
    by all members stay so: the LU folds them. ``boundary`` marks the residuals and Jacobians
    (the iterates need none: what reads them several times, the momentum, is marked shared)."""

    def values(r, scale):
        return member_arrays(r, n_members, dtype), jnp.broadcast_to(scale[()], (n_members,))

    def fn(zt):
        return boundary(values(*residual(from_member_arrays(zt, shape))))

    def fn_jac(zt):
        r, scale, jac = value_and_jacobian(from_member_arrays(zt, shape))
        return boundary(values(r, scale) + (tuple(tuple(row) for row in jac),))

    return fn, fn_jac


def fusion_boundary(tree, always):
    """The member arrays of ``tree`` (arrays of shape (members,), outside object arrays) through a
    conditional on ``always`` (traced, True: its other branch, NaN, is never taken): XLA:CPU
    copies cheap subexpressions into every loop fusion that uses them (a Newton iterate into each
    component of the next residual) and drops optimisation barriers before fusing, but keeps
    conditionals. Marking the iterates and residuals so made the vehicle's generated step 2.8×
    faster (order 1, 64 members per chunk) and compile in 11 s instead of 25 (order 2; ``python
    benchmarks/ensemble_chunks.py``); since the momentum is marked shared the iterates need no
    mark (12 fewer thunks per step on SO(3), ``python benchmarks/generated_step_hlo.py``)."""
    leaves, treedef = jax.tree.flatten(tree)
    slots = [i for i, x in enumerate(leaves) if isinstance(x, jax.Array) and jnp.ndim(x) == 1]
    kept = jax.lax.cond(always, lambda xs: xs, lambda xs: [jnp.full_like(x, jnp.nan) for x in xs], [leaves[i] for i in slots])
    for i, x in zip(slots, kept):
        leaves[i] = x
    return jax.tree.unflatten(treedef, leaves)


def _where(mask, new, old):
    return jax.tree.map(lambda a, b: jnp.where(mask, a, b), new, old)


def _axpy(s, x, y):
    """s·x + y."""
    return tuple(s * a + b for a, b in zip(x, y))


MAX_PERIOD = 16  # steps between two Jacobians of a member at most (carried factors)
EARLY = 1000  # "converged one chord step early": the residual within EARLY × tolerance there


def _is_zero(entry):
    return not isinstance(entry, jax.core.Tracer) and jnp.ndim(entry) == 0 and float(entry) == 0.0


def explicit_block(jac, varies=None):
    """(rows, columns) of a Jacobian (rows of entries: square, or some rows of one), known at
    trace time, where those rows are affine in the unknowns with coefficients that do not depend
    on them, and zero outside those columns, as many as the rows; None if no row is so.
    ``varies[i][j]``: whether entry (i, j) depends on the unknowns (default: whether it is a
    member array, i.e. not shared by all members)."""
    nonzero = [[not _is_zero(e) for e in row] for row in jac]
    if varies is None:
        varies = [[jnp.ndim(e) != 0 for e in row] for row in jac]
    rows = [i for i, (v, nz) in enumerate(zip(varies, nonzero)) if not any(a and b for a, b in zip(v, nz))]
    cols = sorted({j for i in rows for j, b in enumerate(nonzero[i]) if b})
    return (rows, cols) if rows and len(cols) == len(rows) else None


def _reads(jaxpr, flagged):
    """Per output of ``jaxpr``: whether it depends on the inputs ``flagged`` (through conditionals'
    branches and calls precisely, through other primitives conservatively)."""
    seen = {v for v, f in zip(jaxpr.invars, flagged) if f}
    read = lambda v: isinstance(v, jax.extend.core.Var) and v in seen  # noqa: E731
    for eqn in jaxpr.eqns:
        ins = [read(v) for v in eqn.invars]
        if not any(ins):
            continue
        inner = eqn.params.get("jaxpr", eqn.params.get("call_jaxpr"))
        inner = getattr(inner, "jaxpr", inner)
        if eqn.primitive.name == "cond" and not ins[0]:
            outs = [any(o) for o in zip(*(_reads(b.jaxpr, ins[1:]) for b in eqn.params["branches"]))]
        elif isinstance(inner, jax.extend.core.Jaxpr) and len(inner.invars) == len(ins):
            outs = _reads(inner, ins)
        else:
            outs = [True] * len(eqn.outvars)
        seen.update(v for v, o in zip(eqn.outvars, outs) if o)
    return [read(v) for v in jaxpr.outvars]


def jacobian_varies(jacobian, z):
    """Per entry of ``jacobian(z)`` (rows of entries): whether it depends on ``z``, from its jaxpr."""
    closed = jax.make_jaxpr(lambda z: [e for row in jacobian(z) for e in row])(z)
    flat = _reads(closed.jaxpr, [True] * len(closed.jaxpr.invars))
    return [flat[i * len(z) : (i + 1) * len(z)] for i in range(len(z))]


def next_periods(period, ceiling, refreshed, early, fell_back):
    """Each member's refresh period and its ceiling after a step with carried factors. A member
    refreshes its factors at the steps whose count its period divides; only a step on older
    factors tells how long they last: its period doubles (up to the ceiling) when the residual
    before the last chord step was within ``EARLY`` times the tolerance (the last step,
    contracting by the factor ~1e-3 of a near-fresh Jacobian, then converges) and halves
    otherwise. The fallback iterations halve the period and make the halved period the
    member's ceiling from then on (``MAX_PERIOD`` at first): a member whose factors do not last
    one step takes a fresh Jacobian every step. Periods are powers of two: when the members of
    a chunk refresh, all those whose period divides the count do, in one Jacobian evaluation,
    however many there are; the others keep theirs (results are per member)."""
    halved = jnp.maximum(period // 2, 1)
    tested = jnp.where(early, jnp.minimum(2 * period, ceiling), halved)
    period_next = jnp.where(fell_back, halved, jnp.where(refreshed, period, tested))
    return period_next, jnp.where(fell_back, halved, ceiling)


def newton_members(fn, z0, *, rtol, max_iterations, chord_iterations=CHORD_ITERATIONS, value_and_jacobian=None,
                   factors=None, refresh=None, checked_chords=None, rolled=False):
    """Solve ``fn(z) = 0`` for every member at once; ``z`` is a tuple of member arrays and
    ``fn(z) -> (residual, scale)`` (same tuple structure; scale per member) must not couple
    members. ``value_and_jacobian(z) -> (residual, scale, rows)`` gives the Jacobian (default:
    forward mode through ``fn``, column by column). Returns z and per-member (iterations,
    relative residual, result).

    ``factors`` (LU factors of member arrays, as :func:`lu` returns) and ``refresh`` (per member):
    the members with ``refresh`` take the Jacobian at ``z0``, the others keep ``factors``; then
    also returns (the factors to carry: the fallback's last ones where it ran, whether the
    chord steps converged one step early, whether the fallback ran), per member.

    ``checked_chords`` (a :func:`fusion_boundary`): each chord step runs only while some member
    has not converged, and only those members take it, so each member stops at its first
    converged iterate, as ``vj.simulate``'s rolled loop does (its per-member results do not depend
    on the other members); the masked iterates pass the boundary (unmarked, XLA:CPU copies the
    masked solve into every fusion that reads them: 0.6-0.7x on the heavy top). None: every
    chord step runs for every member, unchecked.

    ``rolled`` (with carried ``factors`` and ``checked_chords``, where the full iterations are
    compiled): the same iterations rolled into one loop, the residual and its Jacobian compiled
    once each (:func:`rolled_iterations` inside)."""

    carrying = factors is not None
    n_chord = max(min(chord_iterations, max_iterations - 1), 0)  # chord steps after the Newton step

    def residual_only(z):
        return fn(z)[0]

    def norm(r):
        return vmax(tuple(jnp.abs(c) for c in r))

    def not_converged(r, scale):
        return norm(r) > rtol * scale

    def finite(r):
        out = jnp.isfinite(r[0])
        for c in r[1:]:
            out = out & jnp.isfinite(c)
        return out

    def value_and_jacobian_rows(z):
        if value_and_jacobian is not None:
            return value_and_jacobian(z)
        r, scale = fn(z)
        _, lin = jax.linearize(residual_only, z)
        return r, scale, columns(lin, z)

    def value_and_lu(z):
        r, scale, jac = value_and_jacobian_rows(z)
        return r, scale, lu(jac)

    def as_members(tree):
        return jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x, z0[0].dtype), jnp.shape(z0[0])), tree)

    def first_factors(z):
        """The residual at z, the Jacobian if it is a fresh one for every member, and the factors
        of the first Newton step (None: that Jacobian's, not yet factored)."""
        if not carrying:
            return value_and_jacobian_rows(z) + (None,)

        def fresh(z):
            r, scale, jac = value_and_jacobian_rows(z)
            return r, scale, _where(refresh, as_members(lu(jac)), factors)

        def kept(z):
            return fn(z) + (factors,)

        r, scale, first = jax.lax.cond(jnp.any(refresh), fresh, kept, z)
        return r, scale, None, first

    def solve(_, z):
        if rolled and carrying and checked_chords is not None and max_iterations > 1 + n_chord:
            return rolled_iterations(z)
        r, scale, jac, factors = first_factors(z)
        if factors is None:  # a fresh Jacobian for every member
            block = explicit_block(jac)
            if block is None and any(_is_zero(e) for row in jac for e in row):
                # Coefficients per member (e.g. per-member masses) may still not depend on z.
                block = explicit_block(jac, jacobian_varies(lambda z: value_and_jacobian_rows(z)[2], z))
            if block is not None and len(block[0]) < len(z):
                return solve_explicit_first(z, r, jac, *block)
            factors = lu(jac)
        if jac is not None and all(jnp.ndim(entry) == 0 for row in jac for entry in row):
            # No Jacobian entry is a member array, so none depends on z: fn is affine and one
            # Newton step solves it to round-off (e.g. the inverse Legendre map of a kinetic
            # energy quadratic in the velocities). The statistics are the residual's there (a
            # caller that drops them does not evaluate it). No loop and no fallback to compile.
            z = _axpy(-1.0, lu_solve(factors, r), z)
            r, scale = fn(z)
            return _finish(jnp.ones(jnp.shape(scale), jnp.int32), z, r, scale)

        def chord_step(state):
            i, z, r, scale = state
            z = _axpy(-1.0, lu_solve(factors, r), z)
            return (i + 1, z) + tuple(fn(z))

        def checked_chord_step(state):
            """A chord step by the members not converged yet; their iterates pass the boundary."""
            i, z, r, scale = state
            active = not_converged(r, scale)  # a non-finite member stays so either way
            z = checked_chords(_where(active, _axpy(-1.0, lu_solve(factors, r), z), z))
            return (i + active.astype(i.dtype), z) + _where(active, tuple(fn(z)), (r, scale))

        early = jnp.zeros(jnp.shape(scale), bool)
        state = chord_step((jnp.zeros(jnp.shape(scale), jnp.int32), z, r, scale))  # the Newton step
        for k in range(n_chord):
            if k == n_chord - 1:
                early = norm(state[2]) <= EARLY * rtol * state[3]
            if checked_chords is None:
                state = chord_step(state)
            else:
                going = jnp.any(not_converged(*state[2:]))
                state = jax.lax.cond(going, checked_chord_step, lambda s: s, state)
        i, z, r, scale = state

        def active_of(i, r, scale):
            return (i < max_iterations) & not_converged(r, scale) & finite(r)

        def body(state):
            i, z, r, scale, factors, active = state
            z = _where(active, _axpy(-1.0, lu_solve(factors, r), z), z)
            new = value_and_lu(z)
            r, scale, factors = _where(active, new, (r, scale, factors))
            i = i + active
            return i, z, r, scale, factors, active_of(i, r, scale)

        def fallback(state):
            # Folded (constant or shared) LU entries become member arrays: a loop carry.
            i, z_, r, scale = state
            loop = (i, z_, r, scale, as_members(factors), active_of(i, r, scale))
            i, z_, r, scale, last, _ = jax.lax.while_loop(lambda s: jnp.any(s[-1]), body, loop)
            return (i, _axpy(-1.0, lu_solve(last, r), z_), r, scale) + ((last,) if carrying else ())

        def common(state):  # the final correction with the first Jacobian
            i, z_, r, scale = state
            return (i, _axpy(-1.0, lu_solve(factors, r), z_), r, scale) + ((factors,) if carrying else ())

        fell_back = active_of(i, r, scale)
        if max_iterations <= 1 + n_chord:  # the full iterations could never run: none compiled
            out = common((i, z, r, scale))
        else:
            out = jax.lax.cond(jnp.any(fell_back), fallback, common, (i, z, r, scale))
        if not carrying:
            return _finish(*out[:4])
        return _finish(*out[:4], carry=(out[4], early, fell_back))

    def rolled_iterations(z0):
        """The Newton (or first chord) step, the checked chord steps and the full iterations in
        one ``while`` loop over the evaluations, each of the residual or, where a member needs new
        factors (at its first point if it refreshes, at each of its full iterations), of the
        Jacobian's factors in a conditional whose other branch keeps them: the residual and its
        Jacobian compiled once each, where the unrolled steps hold the residual four times and
        the Jacobian twice. The same iterates, counts and carried factors (each member stops at
        its first converged iterate and takes the final correction there;
        ``tests/test_checked_chords.py`` against a plain loop). For a concrete call's full
        program only, run where some member needs the full iterations (``python
        benchmarks/rolled_full_iterations.py``, a user ``vj.System`` on SO(3), 1024 members, two runs:
        first call 21.4–23.9 → 15.4–18.2 s at order 2 and 32.8–36.1 → 26.5–30.3 s at order 4,
        later calls 0.87–1.09× as long). Rolled everywhere the factors are carried, the steps
        without the full iterations ran 1.06–1.15× as long (the vehicle at orders 2 and 4, a
        throwaway A/B): that program stays unrolled."""
        full_from = 1 + n_chord  # a member's iterations before its first full one
        like = z0[0]
        zeros = tuple(jnp.zeros_like(c) for c in z0)
        no = jnp.zeros(jnp.shape(like), bool)
        state = (jnp.asarray(0, jnp.int32), jnp.zeros(jnp.shape(like), jnp.int32), z0, zeros, jnp.ones_like(like), factors, ~no, no)

        def body(state):
            k, i, z, r, scale, factors, evaluating, early = state
            needs = evaluating & jnp.where(k == 0, refresh, i >= full_from)

            def fresh(z):
                r, scale, jac = value_and_jacobian_rows(z)
                return r, scale, _where(needs, as_members(lu(jac)), factors)

            new = jax.lax.cond(jnp.any(needs), fresh, lambda z: tuple(fn(z)) + (factors,), z)
            r, scale = _where(evaluating, new[:2], (r, scale))
            factors = new[2]
            i = i + (evaluating & (k > 0)).astype(i.dtype)
            if n_chord:  # the residual before the last chord step
                early = jnp.where(k <= n_chord, norm(r) <= EARLY * rtol * scale, early)
            going = (k == 0) | (not_converged(r, scale) & ((i < full_from) | ((i < max_iterations) & finite(r))))
            z = checked_chords(_where(going, _axpy(-1.0, lu_solve(factors, r), z), z))
            return k + 1, i, z, r, scale, factors, going, early

        _, i, z, r, scale, last, _, early = jax.lax.while_loop(lambda s: jnp.any(s[6]), body, state)
        return _finish(i, _axpy(-1.0, lu_solve(last, r), z), r, scale, carry=(last, early, i > full_from))

    def solve_explicit_first(z, r, jac, rows, cols):
        """Rows affine in the unknowns ``cols`` alone, with coefficients that do not depend on
        the unknowns (e.g. the additional dynamics of seed 000 eq. 74, ν explicit): solved
        exactly first; Newton then runs on the other unknowns only, with these fixed."""
        block = lu([[jac[i][j] for j in cols] for i in rows])
        z = list(z)
        for j, dz in zip(cols, lu_solve(block, tuple(r[i] for i in rows))):
            z[j] = z[j] - dz
        rest_rows = [i for i in range(len(z)) if i not in rows]
        rest = [j for j in range(len(z)) if j not in cols]

        def full(z_rest):
            out = list(z)
            for j, c in zip(rest, z_rest):
                out[j] = c
            return tuple(out)

        def fn_rest(z_rest):
            r, scale = fn(full(z_rest))
            return tuple(r[i] for i in rest_rows), scale

        def value_and_jacobian_rest(z_rest):
            r, scale, jac = value_and_jacobian_rows(full(z_rest))
            return tuple(r[i] for i in rest_rows), scale, [[jac[i][j] for j in rest] for i in rest_rows]

        z_rest, (i, rel, result) = newton_members(
            fn_rest, tuple(z[j] for j in rest), rtol=rtol, max_iterations=max_iterations,
            chord_iterations=chord_iterations, value_and_jacobian=value_and_jacobian_rest, checked_chords=checked_chords,
        )
        dtype = z[0].dtype
        return full(z_rest), (i.astype(dtype), rel, result.astype(dtype))

    def _finish(i, z, r, scale, carry=()):
        """z with per-member (iterations, relative residual, result) and what ``factors`` asks
        to carry, r the residual before the last correction (at z for an affine fn)."""
        rel = norm(r) / jnp.where(scale > 0, scale, 1.0)
        ok = finite(z) & finite(r)
        result = jnp.where(~ok, NONFINITE, jnp.where(rel <= rtol, SUCCESS, MAX_ITERATIONS))
        dtype = z[0].dtype  # custom_root's JVP rule mishandles non-float auxiliary outputs
        carry = jax.tree.map(lambda x: x.astype(dtype), carry)
        return z, (i.astype(dtype), rel, result.astype(dtype)) + carry

    def tangent_solve(linear, y):
        return lu_solve(lu(columns(linear, y)), y)

    z, aux = implicit_root(residual_only, z0, solve, tangent_solve)
    i, rel, result = aux[:3]
    stats = jax.lax.stop_gradient((i.astype(jnp.int32), rel, result.astype(jnp.int8)))
    if not carrying:
        return z, stats
    carried, early, fell_back = jax.lax.stop_gradient(aux[3:])
    return z, stats, (carried, early.astype(bool), fell_back.astype(bool))
