"""Unknowns of a DEP step with explicit equations, for ``vj.simulate``'s Newton.

The F⁻ residual's Jacobian is evaluated once, at trace time, on component arrays
(:func:`~._components.componentwise`): the unknowns are member arrays, everything else (the
scene's parameters, h, the state) shared values, so an entry that is a known zero or a shared
value does not depend on the unknowns. Rows affine in as many unknowns alone
(:func:`~._member_newton.explicit_block`: the vehicle's ν at order 1, seed 000 eq. 74) are
solved exactly before Newton (:func:`vi_jax.solvers.newton_root`'s ``explicit``), as the
generated batched step does for ensembles.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ..discrete._dep import _join, discrete_momenta
from ._components import componentwise, components
from ._member_newton import explicit_block, value_and_jacobian_of

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
    with explicit equations, or None (none, or every unknown: Newton then solves the whole
    system). Traced abstractly: nothing is added to the caller's program.

    Only scenes with additional dynamics are analysed (their P rows are where such equations
    arise, eq. 74): the trace costs a step's Jacobian on components, 0.17 s on the vehicle but
    0.3–0.5 s on the heavy top on SO(4) and 1.5–3 s on SO(6), whose unknowns ξ have none. The
    answer depends on the scene's structure only (its parameters are unknown values here), so
    it is kept for the next program of the same structure."""
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
    jacobian = componentwise(value_and_jacobian_of(dep_residual(static, tau, rule), 2), ANALYSIS_MEMBERS)
    n, a = jax.eval_shape(lambda s, g, q: (s.body_configuration(g, q), s.body_advected(g)), system, state.g, state.q)
    target = jax.eval_shape(_join, state.M, state.P)
    unknowns = state.z.shape[0]
    found = []

    def analyse(params, h, z, n, a, target):
        shared = lambda x: None if x is None else components(x, False)  # noqa: E731
        _, _, jac = jacobian(jax.tree.map(shared, params), shared(h), components(z, True), shared(n), shared(a), shared(target))
        found.append(explicit_block([list(row) for row in jac]))

    spec = lambda x: jax.ShapeDtypeStruct(jnp.shape(x), x.dtype)  # noqa: E731
    z = jax.ShapeDtypeStruct((ANALYSIS_MEMBERS,) + state.z.shape, state.z.dtype)
    jax.make_jaxpr(analyse)(jax.tree.map(spec, params), spec(h), z, n, a, target)
    block = found[0]
    return None if block is None or len(block[0]) == unknowns else block
