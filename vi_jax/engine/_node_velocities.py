"""Node velocities of a saved trajectory: the continuous inverse Legendre map, (ξ, ν) with
(ℓ_ξ, ℓ_ν)(ξ, n, ν, a) = (M, P) (seed 000 spec §2), at every node at once.

The nodes take the members' place in the generated step's machinery: the residual and its
forward-mode Jacobian run on component arrays of shape (nodes,) and Newton on their tuples
(:func:`newton_members`, implicit-function gradients), so the solve is elementwise over the
nodes instead of a ``vmap`` of a per-node Newton with small matrices. The residuals pass a
fusion boundary (:func:`fusion_boundary`): each is computed once, not again inside every
component of the velocities that reads it.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..discrete._dep import _join, _split
from ._components import componentwise, components, from_member_arrays, member_arrays, stacked
from ._member_newton import fusion_boundary, newton_members, on_member_tuples, value_and_jacobian_of


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

    body_c, residual_c, jacobian_c = (componentwise(f, n_nodes) for f in (body, residual, value_and_jacobian_of(residual, 1)))
    params = jax.tree.map(lambda x: components(x, False), params)
    per_node = lambda x: None if x is None else components(x, True)  # noqa: E731
    n, a = body_c(params, per_node(states.g), per_node(states.q))
    target = per_node(states.M) if states.P is None else np.concatenate([per_node(states.M), per_node(states.P)])
    shape = states.z.shape[1:]

    always = states.M[0, 0] == states.M[0, 0]  # True unless the initial momentum is NaN (then every node is)
    fn, fn_jac = on_member_tuples(
        lambda z: residual_c(params, z, n, a, target), lambda z: jacobian_c(params, z, n, a, target), shape, n_nodes, dtype,
        lambda tree: fusion_boundary(tree, always),
    )
    z0 = member_arrays(per_node(states.z), n_nodes, dtype)
    z, _ = newton_members(fn, z0, rtol=rtol, max_iterations=max_iter, value_and_jacobian=fn_jac)
    z = stacked(from_member_arrays(z, shape), n_nodes)
    if not system.has_additional:
        return z, None
    r = system.group.dim
    return z[:, :r], z[:, r:]
