"""The trajectory every scheme returns (:class:`Solution`) and the input checks they share."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import _validation as val
from .._diagnostics import kelvin_noether, kelvin_noether_scale
from ._components import components, componentwise, stacked
from .._system import AbstractSystem, State
from ..solvers import SUCCESS


class Solution(eqx.Module):
    """Trajectory at the saved nodes (leading axis = time, n_saved + 1 rows).

    ``g``/``R``: configuration; ``xi``/``omega``: body velocity and ``nu``: body velocity of the
    additional dynamics, both from the continuous inverse Legendre map at the nodes; ``M``, ``P``:
    body momenta (the discrete ones for ``scheme="dep"``, the continuous ones, which are the
    state, for ``scheme="splitting"``); ``energy``; ``kelvin_noether`` (a scalar per node when the isotropy
    algebra is one-dimensional, else one column per basis element) and ``kelvin_noether_scale``
    (|M| + |P||n|, the size of the terms that cancel in it). Newton statistics per saved node
    (the worst over the steps since the previous saved node; row 0 is the initial data):
    ``newton_iterations``, ``newton_residual`` (relative), ``result`` (0 = success; an explicit
    scheme has no Newton solve: zeros).
    """

    t: jax.Array
    g: jax.Array
    xi: jax.Array
    q: jax.Array | None
    nu: jax.Array | None
    M: jax.Array
    P: jax.Array | None
    energy: jax.Array
    kelvin_noether: jax.Array
    kelvin_noether_scale: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    result: jax.Array

    @property
    def R(self):
        return self.g

    @property
    def omega(self):
        return self.xi

    @property
    def succeeded(self):
        return jnp.all(self.result == SUCCESS)


COMPONENTWISE_MATRIX_SIZE = 4  # node_invariants on component arrays up to 4×4 group matrices


def node_invariants(system, g, q, M, P, xi, nu):
    """Energy, Kelvin–Noether (a scalar per node for a one-dimensional isotropy algebra) and its
    scale at nodes (leading axis) with body momenta (M, P) and velocities (ξ, ν).

    For groups of matrices up to 4×4 (SO(3), SE(3), the tops and the vehicle) they are computed
    on component arrays of shape (nodes,) (:func:`~._components.componentwise`), as the node
    velocities are: 65,536 vehicle nodes in 1.6 ms, against 9.4 ms for a ``vmap`` of the
    per-node functions. Larger groups keep the ``vmap``: there the components multiply the
    traced operations (SO(6): 1.07 s to trace and compile against 0.21 s; ``python
    benchmarks/node_invariants.py``)."""
    n_nodes = M.shape[0]
    params, static = eqx.partition(system, eqx.is_array)

    def per_node(p, g, q, M, P, xi, nu):
        s = eqx.combine(p, static)
        n, a = s.body_configuration(g, q), s.body_advected(g)
        return s.energy(xi, n, nu, a), kelvin_noether(s, g, q, M, P), kelvin_noether_scale(s, g, q, M, P)

    if system.group.matrix_size <= COMPONENTWISE_MATRIX_SIZE:
        nodes = lambda x: None if x is None else components(x, True)  # noqa: E731
        outs = componentwise(per_node, n_nodes)(jax.tree.map(lambda x: components(x, False), params), *map(nodes, (g, q, M, P, xi, nu)))
        energy, kn, kn_scale = (stacked(o, n_nodes).astype(M.dtype) for o in outs)
    else:
        energy, kn, kn_scale = jax.vmap(per_node, in_axes=(None, 0, 0, 0, 0, 0, 0))(params, g, q, M, P, xi, nu)
    if kn.shape[-1] == 1:
        kn = kn[..., 0]
    return energy, kn, kn_scale


def validate_inputs(system, x0, h, n_steps, save_every, values=True):
    """Checks every scheme makes: the scene, x0's shapes, h > 0, step counts and, with
    ``values``, x0 on the group and every float value finite (``values=False``: left to the
    caller, e.g. checked for every member of an ensemble by :func:`~vi_jax._validation.check_values`)."""
    if not isinstance(system, AbstractSystem):
        raise ValueError(f"system: expected a vi_jax system (AbstractSystem), got {type(system).__name__}")
    if not isinstance(x0, State):
        raise ValueError(f"x0: expected a vi_jax.State (e.g. model.initial_state()), got {type(x0).__name__}")
    G = system.group
    d, r = G.matrix_size, G.dim
    g0 = val.as_array("x0.g", x0.g, (d, d))
    xi0 = val.as_array("x0.xi", x0.xi, (r,))
    if values:
        val.check_finite("x0.g", g0)
        val.check_finite("x0.xi", xi0)
        val.check_on_group("x0.g", G, g0)
    if system.has_additional:
        if x0.q is None or x0.qdot is None:
            raise ValueError("x0: this system has additional dynamics; expected x0.q and x0.qdot, got None")
        m = jnp.shape(x0.q)[-1] if jnp.ndim(x0.q) else None
        val.as_array("x0.q", x0.q, (m,))
        val.as_array("x0.qdot", x0.qdot, (m,))
        if values:
            val.check_finite("x0.q", x0.q)
            val.check_finite("x0.qdot", x0.qdot)
    elif x0.q is not None or x0.qdot is not None:
        raise ValueError("x0: this system has no additional dynamics; expected x0.q = x0.qdot = None")
    if values:
        val.check_finite("system parameters", val.numeric_leaves(system))
    h = val.check_positive_scalar("h", h)
    n_steps, save_every = val.check_steps(n_steps, save_every)
    return h, n_steps, save_every
