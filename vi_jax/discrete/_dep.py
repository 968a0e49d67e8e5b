"""The discrete Euler–Poincaré equations with advected parameters and additional dynamics
(seed 000 eq. 42 with 43–44) in momentum (discrete Legendre) form, for any scene.

Per step, with Λ = τ(hξ), n = ρ_Q(g_k)⁻¹q_k, a = ρ_V(g_k)⁻¹a₀ and the velocity-form discrete
Lagrangian ℓ̃(ξ, n, ν, a) (seed 000 spec §2):

  F⁻:  M_k = (dτ⁻¹_{hξ})* ℓ̃_ξ − h(ℓ̃_a◇a + ℓ̃_n◇n + ℓ̃_ν◇ν),    P_k = ℓ̃_ν − hℓ̃_n
  F⁺:  M_{k+1} = (dτ⁻¹_{−hξ})* ℓ̃_ξ,                           P_{k+1} = ρ_Q(Λ)ᵀℓ̃_ν

F⁻ = (M_k, P_k) is solved for (ξ, ν) by Newton; F⁻ = F⁺ across a node is eq. (42).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._shared_values import shared
from ..lie._small import with_fused_products
from ..solvers import SINGULAR_DIFFERENCE_MAP, newton_root
from ._quadrature import discrete_lagrangian


class StepState(eqx.Module):
    """Discrete state at a node: g_k, q_k, body momenta M_k, P_k, and the last step's
    unknowns (ξ, ν) used as the next Newton guess."""

    g: jax.Array
    q: jax.Array | None
    M: jax.Array
    P: jax.Array | None
    z: jax.Array


class StepStats(eqx.Module):
    iterations: jax.Array
    residual: jax.Array
    result: jax.Array

    @classmethod
    def zeros(cls, dtype) -> "StepStats":
        """No iterations, zero residual, ``SUCCESS``: the start of a running maximum. Built
        directly: shape-evaluating a step for it would trace the whole step once more."""
        return cls(jnp.zeros((), jnp.int32), jnp.zeros((), dtype), jnp.zeros((), jnp.int8))


def _split(system, z):
    r = system.group.dim
    return (z[:r], z[r:]) if system.has_additional else (z, None)


def _join(xi, nu):
    return xi if nu is None else jnp.concatenate([xi, nu])


def discrete_momenta(system, tau, rule, h, z, n, a):
    """F⁻ (M_k, P_k), F⁺ (M_{k+1}, P_{k+1}) and the size of the F⁻ terms (for tolerances)."""
    G = system.group
    xi, nu = _split(system, z)
    grads = jax.grad(
        lambda *args: discrete_lagrangian(system, tau, rule, h, *args), argnums=(0, 1, 2, 3)
    )(xi, n, nu, a)
    l_xi, l_n, l_nu, l_a = grads
    l_xi = shared(l_xi)  # read by every component of both momenta
    m_tau = tau.dtau_inv_dual(G, h * xi, l_xi)
    m_minus = m_tau
    size_m = jnp.abs(m_tau)
    if a is not None:
        term = h * system.advected_action.diamond(l_a, a)
        m_minus = m_minus - term
        size_m = size_m + jnp.abs(term)
    p_minus = p_plus = None
    size_p = jnp.zeros((0,), z.dtype)
    if n is not None:
        Q = system.configuration_action
        term = h * (Q.diamond(l_n, n) + Q.diamond(l_nu, nu))
        m_minus = m_minus - term
        size_m = size_m + jnp.abs(term)
        p_minus = l_nu - h * l_n
        size_p = jnp.abs(l_nu) + h * jnp.abs(l_n)
        p_plus = Q.act_transpose(tau.tau(G, h * xi), l_nu)
    m_plus = tau.dtau_inv_dual(G, -h * xi, l_xi)
    scale = jnp.maximum(jnp.max(size_m), jnp.max(size_p, initial=0.0))
    return (m_minus, p_minus), (m_plus, p_plus), scale


def dep_step(system, tau, rule, h, state: StepState, *, rtol, max_iterations, explicit=None):
    """One step (g_k, q_k, M_k, P_k) ↦ (g_{k+1}, q_{k+1}, M_{k+1}, P_{k+1}); ``explicit``: the
    unknowns with explicit equations (:func:`vi_jax.solvers.newton_root`)."""
    G = system.group
    n, a = with_fused_products(lambda g, q: (system.body_configuration(g, q), system.body_advected(g)))(state.g, state.q)
    target = _join(state.M, state.P)

    def residual(z):
        (m, p), _, scale = discrete_momenta(system, tau, rule, h, z, n, a)
        return _join(m, p) - target, scale

    z, stats = newton_root(residual, state.z, rtol=rtol, max_iterations=max_iterations, explicit=explicit)

    def update(z):
        xi, nu = _split(system, z)
        _, (m_next, p_next), _ = discrete_momenta(system, tau, rule, h, z, n, a)
        lam = tau.tau(G, h * xi)
        q_next = None
        if system.has_additional:
            q_next = state.q + h * system.configuration_action.act(state.g, nu)
        return StepState(G.compose(state.g, lam), q_next, m_next, p_next, z), tau.is_regular(G, h * xi)

    new_state, regular = with_fused_products(update)(z)
    result = jnp.where(regular, stats.result, SINGULAR_DIFFERENCE_MAP)
    return new_state, StepStats(stats.iterations, stats.residual, result.astype(jnp.int8))


def legendre_initial_state(system, g0, xi0, q0=None, qdot0=None) -> StepState:
    """M₀ = ℓ_ξ, P₀ = ℓ_ν from the continuous Legendre map at the initial data (seed 000 spec
    §2 "Initialisation"); the first Newton guess is the continuous velocity."""
    n0 = system.body_configuration(g0, q0)
    nu0 = system.configuration_action.act_inverse(g0, qdot0) if system.has_additional else None
    a0 = system.body_advected(g0)
    mu, p = system.momenta(xi0, n0, nu0, a0)
    return StepState(g0, q0, mu, p, _join(xi0, nu0))


def inverse_legendre(system, g, q, M, P, guess, *, rtol, max_iterations):
    """Node velocities (ξ, ν) with (ℓ_ξ, ℓ_ν)(ξ, n, ν, a) = (M, P)."""
    n = system.body_configuration(g, q)
    a = system.body_advected(g)
    target = _join(M, P)

    def residual(z):
        xi, nu = _split(system, z)
        mu, p = system.momenta(xi, n, nu, a)
        value = _join(mu, p)
        return value - target, jnp.max(jnp.abs(target)) + jnp.max(jnp.abs(value))

    z, _ = newton_root(residual, guess, rtol=rtol, max_iterations=max_iterations)
    return _split(system, z)
