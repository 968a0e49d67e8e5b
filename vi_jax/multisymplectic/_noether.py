"""Discrete momentum maps and energies (seed 003 eqs. 35–38, 57, 77, 94, 98–99; spec §§1, 3).

For the symmetry by left translation, ζ_G(g) = ζg, the momentum map of vertex k of a triangle
is J^k = Ad*_{(g⁽ᵏ⁾)⁻¹} P^k (eq. 35 with the left-trivialised P^k of eq. 64), the spatial
momentum of that vertex. Invariance gives J¹ + J² + J³ = 0 on every triangle (eq. 36).
"""

import jax
import jax.numpy as jnp

from ._lagrangian import _on_triangles, density_gradients, field_function, field_velocities, triangle_vertex_momenta


def spatial_sum(group, g, m, weight):
    """Σ_i weight·Ad*_{g_i⁻¹} m_i over the second-to-last axis of g (…, n, d, d) and m (…, n, r)."""
    spatial = jnp.vectorize(group.Ad_dual_inv, signature="(d,d),(r)->(r)")(g, m)
    return weight * jnp.sum(spatial, axis=-2)


def time_energy_density(system, xi, eta):
    """⟨∂ℓ/∂ξ, ξ⟩ − ℓ: K + Φ for ℓ = K − Φ, the integrand of E_L (eq. 98)."""
    return density_gradients(system, xi, eta)[0] @ xi - system.lagrangian(xi, eta)


def space_energy_density(system, xi, eta):
    """⟨∂ℓ/∂η, η⟩ − ℓ: −K − ⟨ℂ(η − E₆), E₆⟩ − Φ for the beam, the integrand of E_N (eq. 99)."""
    return density_gradients(system, xi, eta)[1] @ eta - system.lagrangian(xi, eta)


@field_function
def triangle_momentum_maps(system, g, *, dt, ds, tau="cayley"):
    """(J¹, J², J³) on every triangle of the field, each of shape (rows − 1, cols − 1, r):
    J^k = Ad*_{(g⁽ᵏ⁾)⁻¹}P^k at the vertex's own configuration (eqs. 35, 77)."""
    G = system.group

    def maps(g1, g2, g3):
        P1, P2, P3 = triangle_vertex_momenta(system, tau, dt, ds, g1, g2, g3)
        return G.Ad_dual_inv(g1, P1), G.Ad_dual_inv(g2, P2), G.Ad_dual_inv(g3, P3)

    return _on_triangles(maps, g)


@field_function
def time_momentum_map(system, g, *, dt, ds, tau="cayley"):
    """𝖩⁺_𝖫(j) = Σ_a J²(△_a^j) (eqs. 57, 94), shape (rows − 1, r): Σ_a Δs Ad*_{(g_a^j)⁻¹}μ_a^j."""
    return jnp.sum(triangle_momentum_maps(system, g, dt=dt, ds=ds, tau=tau)[1], axis=1)


@field_function
def space_momentum_map(system, g, *, dt, ds, tau="cayley"):
    """𝖩⁺_𝖭(a) = Σ_j J³(△_a^j) (eqs. 57, 94), shape (cols − 1, r): Σ_j Δt Ad*_{(g_a^j)⁻¹}λ_a^j."""
    return jnp.sum(triangle_momentum_maps(system, g, dt=dt, ds=ds, tau=tau)[2], axis=0)


def covariant_momentum(J1, J2, J3, rows, cols):
    """𝒥_{B,C}^{K,L} of Theorem 3.3 (eqs. 37–38) for triangles K ≤ j ≤ L, B ≤ a ≤ C: the sum of the
    momentum maps at the boundary nodes of the rectangle; zero when the DCEL holds inside.
    Returns (𝒥, Σ of the magnitudes of its terms)."""
    (K, L), (B, C) = rows, cols
    terms = [
        J1[K + 1 : L + 1, B] + J2[K:L, B],  # left edge, j = K+1..L
        J3[K + 1 : L + 1, C],  # right edge, j = K+1..L
        J1[K, B + 1 : C + 1] + J3[K, B:C],  # bottom edge, a = B+1..C
        J2[L, B + 1 : C + 1],  # top edge, a = B+1..C
        (J1[K, B] + J2[L, B] + J3[K, C])[None],  # corners
    ]
    total = sum(jnp.sum(t, axis=0) for t in terms)
    scale = sum(jnp.sum(jnp.abs(t), axis=0) for t in terms)
    return total, scale


def _energies(system, g, dt, ds, tau, density):
    xi, eta = field_velocities(system, g, dt=dt, ds=ds, tau=tau)
    return jax.vmap(jax.vmap(lambda x, e: density(system, x, e)))(xi, eta)


@field_function
def time_energy(system, g, *, dt, ds, tau="cayley"):
    """E_L(j) = Σ_a Δs (⟨ℓ_ξ, ξ⟩ − ℓ)(ξ_a^j, η_a^j) (spec §3, eq. 98), shape (rows − 1,)."""
    return ds * jnp.sum(_energies(system, g, dt, ds, tau, time_energy_density), axis=1)


@field_function
def space_energy(system, g, *, dt, ds, tau="cayley"):
    """E_N(a) = Σ_j Δt (⟨ℓ_η, η⟩ − ℓ)(ξ_a^j, η_a^j) (spec §3, eq. 99), shape (cols − 1,)."""
    return dt * jnp.sum(_energies(system, g, dt, ds, tau, space_energy_density), axis=0)
