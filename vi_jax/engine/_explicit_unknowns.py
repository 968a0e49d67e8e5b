"""Unknowns of a DEP step with explicit equations, for ``vj.simulate``'s Newton.

The Jacobian of the F⁻ residual's P rows (the additional dynamics, where such equations arise:
eq. 74; the M rows hold τ's terms nonlinear in ξ) is evaluated once, at trace time, on component
arrays (:func:`~._components.componentwise`): the unknowns are member arrays, everything else
(the scene's parameters, h, the state) shared values, so an entry that is a known zero or a
shared value does not depend on the unknowns. Rows affine in as many unknowns alone
(:func:`~._member_newton.explicit_block`: the vehicle's ν at order 1, seed 000 eq. 74) are
solved exactly before Newton (:func:`vi_jax.solvers.newton_root`'s ``explicit``), as the
generated batched step does for ensembles.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ..discrete._dep import _join, discrete_momenta
from ._components import componentwise, components
from ._member_newton import explicit_block

ANALYSIS_MEMBERS = 2  # any number above one: the unknowns' components are arrays of this size


def dep_residual(static, tau, rule):
    """The F⁻ residual ``(params, h, z, n, a, target) -> (residual, scale)`` of a scene whose
    array leaves are ``params`` (and other leaves ``static``)."""

    def residual(params, h, z, n, a, target):
        (m, p), _, scale = discrete_momenta(eqx.combine(params, static), tau, rule, h, z, n, a)
        return _join(m, p) - target, scale

    return residual


_FOUND = {}  # (the scene's structure, τ, rule, argument shapes) -> explicit_unknowns' answer


def explicit_unknowns(system, tau, rule, state, h):
    """(rows, columns) of the DEP residual at ``state`` (a :class:`~vi_jax.discrete.StepState`)
    with explicit equations, or None (none: Newton then solves the whole system; the P rows
    alone never cover every unknown). Traced abstractly: nothing is added to the caller's program.

    Only scenes with additional dynamics are analysed, their P rows alone: the trace costs the
    Jacobian of those rows on components, 0.14–0.17 s on the vehicle in a fresh process against
    0.31–0.34 s for the whole residual's (five alternate processes of both versions, a throwaway
    script timing ``explicit_unknowns``); a scene without them (the heavy top on SO(4):
    0.3–0.5 s, SO(6): 1.5–3 s for the whole residual) is not analysed. The answer depends on the scene's structure only (its parameters are unknown
    values here), so it is kept for the next program of the same structure."""
    if not system.has_additional:
        return None
    avals = lambda tree: tuple((jnp.shape(x), jnp.result_type(x)) for x in jax.tree.leaves(tree))  # noqa: E731
    key = (jax.tree.structure(system), tau, rule, avals(system), avals(state), avals(h))
    try:
        return _FOUND[key]
    except KeyError:
        pass
    except TypeError:  # a static field that cannot be hashed: analysed every time
        key = None
    found = _analyse(system, tau, rule, state, h)
    if key is not None:
        _FOUND[key] = found
    return found


def _analyse(system, tau, rule, state, h):
    params, static = eqx.partition(system, eqx.is_array)
    first = state.M.shape[0]  # the P rows follow the M rows

    def p_rows_jacobian(params, h, z, n, a, target):
        # The P rows' own function: the whole residual's rows sliced still traces the M rows'
        # terms and the scale (0.30–0.45 s against 0.17–0.28 s: the same throwaway script).
        def p_rows(z):
            (_, p), _, _ = discrete_momenta(eqx.combine(params, static), tau, rule, h, z, n, a)
            return p - target[first:]

        return jax.jacfwd(p_rows)(z)

    jacobian = componentwise(p_rows_jacobian, ANALYSIS_MEMBERS)
    n, a = jax.eval_shape(lambda s, g, q: (s.body_configuration(g, q), s.body_advected(g)), system, state.g, state.q)
    target = jax.eval_shape(_join, state.M, state.P)
    found = []

    def analyse(params, h, z, n, a, target):
        shared = lambda x: None if x is None else components(x, False)  # noqa: E731
        jac = jacobian(jax.tree.map(shared, params), shared(h), components(z, True), shared(n), shared(a), shared(target))
        found.append(explicit_block([list(row) for row in jac]))

    spec = lambda x: jax.ShapeDtypeStruct(jnp.shape(x), x.dtype)  # noqa: E731
    z = jax.ShapeDtypeStruct((ANALYSIS_MEMBERS,) + state.z.shape, state.z.dtype)
    jax.make_jaxpr(analyse)(jax.tree.map(spec, params), spec(h), z, n, a, target)
    block = found[0]
    return None if block is None else ([first + i for i in block[0]], block[1])
