"""Diagnostics at the nodes of a trajectory: energy, the Kelvin–Noether quantity, the
group-constraint residual."""

import jax
import jax.numpy as jnp


def kelvin_noether(system, g, q, M, P):
    """J = Bᵀ Ad*_{g⁻¹}(M − P◇n), B a basis of the isotropy algebra g_{a₀}: the discrete
    Kelvin–Noether quantity of seed 000 Thm 7 / eqs. (77)–(78) in momentum form (spec §2);
    conserved exactly by the DEP step for ζ ∈ g_{a₀}. Without V* it is the spatial momentum."""
    mu = M
    if system.has_additional:
        mu = M - system.configuration_action.diamond(P, system.body_configuration(g, q))
    basis = system.isotropy_basis(M.dtype)
    return basis.T @ system.group.Ad_dual_inv(g, mu)


def kelvin_noether_scale(system, g, q, M, P):
    """|M| + |P||n|: the size of the terms that cancel in the Kelvin–Noether quantity."""
    scale = jnp.linalg.norm(M)
    if system.has_additional:
        scale = scale + jnp.linalg.norm(P) * jnp.linalg.norm(system.body_configuration(g, q))
    return scale


def group_constraint_residual(system, g):
    """‖g − G‖ per node, e.g. ‖RᵀR − I‖_F on SO(3); accepts a leading time axis."""
    return jax.vmap(system.group.membership_error)(g.reshape((-1,) + g.shape[-2:])).reshape(g.shape[:-2])
