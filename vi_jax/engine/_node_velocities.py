"""Node velocities of a saved trajectory: the continuous inverse Legendre map, (ξ, ν) with
(ℓ_ξ, ℓ_ν)(ξ, n, ν, a) = (M, P) (seed 000 spec §2), at every node at once.

The nodes take the members' place in the generated step's machinery: the residual and its
forward-mode Jacobian run on component arrays of shape (nodes,) and Newton on their tuples
(:func:`newton_members`, implicit-function gradients), so the solve is elementwise over the
nodes instead of a ``vmap`` of a per-node Newton with small matrices.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..discrete._dep import _join, _split
from ._components import componentwise, components, from_member_arrays, member_arrays, stacked
from ._member_newton import newton_members


def node_velocities(system, states, rtol, max_iter):
    """(ξ, ν) at every saved node of ``states`` (leading axis = node; ν is None without
    additional dynamics), started from the step unknowns ``states.z``."""
    n_nodes = states.M.shape[0]
    dtype = states.M.dtype
    params, static = eqx.partition(system, eqx.is_array)

    def scene(p):
        return eqx.combine(p, static)

    def body(p, g, q):
        s = scene(p)
        return s.body_configuration(g, q), s.body_advected(g)

    def residual(p, z, n, a, target):
        s = scene(p)
        xi, nu = _split(s, z)
        value = _join(*s.momenta(xi, n, nu, a))
        return value - target, jnp.max(jnp.abs(target)) + jnp.max(jnp.abs(value))

    def value_and_jacobian(p, z, n, a, target):
        def with_aux(z):
            r, scale = residual(p, z, n, a, target)
            return r, (r, scale)

        jac, (r, scale) = jax.jacfwd(with_aux, has_aux=True)(z)
        return r, scale, jac

    body_c, residual_c, jacobian_c = (componentwise(f, n_nodes) for f in (body, residual, value_and_jacobian))
    params = jax.tree.map(lambda x: components(x, False), params)
    per_node = lambda x: None if x is None else components(x, True)  # noqa: E731
    n, a = body_c(params, per_node(states.g), per_node(states.q))
    target = per_node(states.M) if states.P is None else np.concatenate([per_node(states.M), per_node(states.P)])
    shape = states.z.shape[1:]

    def fn(zt):
        r, scale = residual_c(params, from_member_arrays(zt, shape), n, a, target)
        return member_arrays(r, n_nodes, dtype), jnp.broadcast_to(scale[()], (n_nodes,))

    def fn_jac(zt):
        r, scale, jac = jacobian_c(params, from_member_arrays(zt, shape), n, a, target)
        return member_arrays(r, n_nodes, dtype), jnp.broadcast_to(scale[()], (n_nodes,)), tuple(tuple(row) for row in jac)

    z0 = member_arrays(per_node(states.z), n_nodes, dtype)
    z, _ = newton_members(fn, z0, rtol=rtol, max_iterations=max_iter, value_and_jacobian=fn_jac)
    z = stacked(from_member_arrays(z, shape), n_nodes)
    if not system.has_additional:
        return z, None
    r = system.group.dim
    return z[:, :r], z[:, r:]
