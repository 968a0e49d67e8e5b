"""The covariant scene and its discrete Lagrangian on the triangle grid (seed 003 §§3.1, 4).

Grid: nodes (j, a), t_j = jΔt, s_a = aΔs; triangle △_a^j = ((j, a), (j+1, a), (j, a+1)).
A field is an array ``g`` of shape (rows, columns, d, d) = (time, space, d, d).

On △_a^j the left-trivialised velocities are (eq. 63)
    ξ = τ⁻¹(g₁⁻¹g₂)/Δt,   η = τ⁻¹(g₁⁻¹g₃)/Δs,
the discrete Lagrangian is L̄_d = ΔsΔt ℓ(ξ, η) (spec §3, the triangle quadrature), and the
discrete momenta, normalised per unit area (spec §3; eq. 64 divided by ΔsΔt), are
    μ = (dτ⁻¹_{Δtξ})* ∂ℓ/∂ξ,   λ = (dτ⁻¹_{Δsη})* ∂ℓ/∂η.
The left-trivialised vertex derivatives of L_d (eqs. 64, 76) are
    P¹ = −(Δs μ + Δt λ),   P² = Δs Ad*_{τ(Δtξ)} μ,   P³ = Δt Ad*_{τ(Δsη)} λ,
and the Lie-group DCEL (68)–(71) (with D_gL̄ = 0: eqs. 82–83) is their sum at each node.
"""

import abc
import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from ..lie import AbstractMatrixGroup, difference_map


class AbstractCovariantSystem(eqx.Module):
    """A G-invariant field theory on 1+1 spacetime: a Lie group and a Lagrangian density
    ℓ(ξ, η) of the time velocity ξ = g⁻¹∂_t g and the space velocity η = g⁻¹∂_s g (eq. 95's
    form). Subclass, implement :attr:`group` and :meth:`lagrangian`; parameters are fields."""

    @property
    @abc.abstractmethod
    def group(self) -> AbstractMatrixGroup: ...

    @abc.abstractmethod
    def lagrangian(self, xi, eta):
        """ℓ(ξ, η), per unit time and unit length."""


class CovariantSystem(AbstractCovariantSystem):
    """A covariant system from a plain function ``lagrangian(xi, eta)`` on any group of
    :mod:`vi_jax.lie` (its array parameters, if it is an equinox Module, are differentiable)."""

    lie_group: AbstractMatrixGroup
    density: Callable

    def __init__(self, group: AbstractMatrixGroup, lagrangian: Callable):
        if not isinstance(group, AbstractMatrixGroup):
            raise ValueError(f"group: expected a vi_jax.lie group, got {type(group).__name__}")
        if not callable(lagrangian):
            raise ValueError(f"lagrangian: expected a function (xi, eta) -> scalar, got {lagrangian!r}")
        self.lie_group = group
        self.density = lagrangian

    @property
    def group(self):
        return self.lie_group

    def lagrangian(self, xi, eta):
        return self.density(xi, eta)


def density_gradients(system, xi, eta):
    """(∂ℓ/∂ξ, ∂ℓ/∂η) by autodiff."""
    return jax.grad(system.lagrangian, argnums=(0, 1))(xi, eta)


def dual_Ad(group, g, mu):
    """Ad*_g μ = Ad_gᵀ μ (spec §2: ⟨Ad*_g μ, x⟩ = ⟨μ, Ad_g x⟩)."""
    return group.Ad(g).T @ mu


def triangle_velocities(system, tau, dt, ds, g1, g2, g3):
    """(ξ, η) on one triangle, eq. (63)."""
    G = system.group
    g1_inv = G.inverse(g1)
    return tau.tau_inv(G, g1_inv @ g2) / dt, tau.tau_inv(G, g1_inv @ g3) / ds


def triangle_momenta(system, tau, dt, ds, xi, eta):
    """(μ, λ) per unit area (spec §3): μ = (dτ⁻¹_{Δtξ})*ℓ_ξ, λ = (dτ⁻¹_{Δsη})*ℓ_η."""
    G = system.group
    l_xi, l_eta = density_gradients(system, xi, eta)
    return tau.dtau_inv_dual(G, dt * xi, l_xi), tau.dtau_inv_dual(G, ds * eta, l_eta)


def triangle_vertex_momenta(system, tau, dt, ds, g1, g2, g3):
    """Left-trivialised vertex derivatives (P¹, P², P³) = (g⁽ᵏ⁾)⁻¹D_kL_d, eqs. (64)/(76)."""
    G = system.group
    xi, eta = triangle_velocities(system, tau, dt, ds, g1, g2, g3)
    mu, lam = triangle_momenta(system, tau, dt, ds, xi, eta)
    P1 = -(ds * mu + dt * lam)
    P2 = ds * dual_Ad(G, tau.tau(G, dt * xi), mu)
    P3 = dt * dual_Ad(G, tau.tau(G, ds * eta), lam)
    return P1, P2, P3


def triangle_lagrangian(system, tau, dt, ds, g1, g2, g3):
    """L̄_d(△) = ΔsΔt ℓ(ξ, η) (spec §3)."""
    xi, eta = triangle_velocities(system, tau, dt, ds, g1, g2, g3)
    return ds * dt * system.lagrangian(xi, eta)


def field_function(fn):
    """Compile ``fn(*arrays, dt, ds, tau, …)`` once per shape: the steps become arrays of the
    field's precision, ``tau`` a difference-map instance (names or instances accepted)."""
    jitted = eqx.filter_jit(fn)

    @functools.wraps(fn)
    def wrapper(system, g, *args, dt, ds, tau="cayley", **kwargs):
        dtype = jnp.result_type(g)
        if "t0" in kwargs:
            kwargs["t0"] = jnp.asarray(kwargs["t0"], dtype)
        args = tuple(jnp.asarray(x) if isinstance(x, (tuple, list)) else x for x in args)
        steps = dict(dt=jnp.asarray(dt, dtype), ds=jnp.asarray(ds, dtype))
        return jitted(system, g, *args, **steps, tau=difference_map(tau), **kwargs)

    return wrapper


def _on_triangles(fn, g):
    """Apply ``fn(g1, g2, g3)`` to every triangle △_a^j of a field g (rows, cols, d, d)."""
    return jax.vmap(jax.vmap(fn))(g[:-1, :-1], g[1:, :-1], g[:-1, 1:])


@field_function
def field_velocities(system, g, *, dt, ds, tau="cayley"):
    """(ξ_a^j, η_a^j) on every triangle: two arrays of shape (rows − 1, cols − 1, r)."""
    return _on_triangles(lambda *v: triangle_velocities(system, tau, dt, ds, *v), g)


@field_function
def vertex_momenta(system, g, *, dt, ds, tau="cayley"):
    """(P¹, P², P³) on every triangle, each of shape (rows − 1, cols − 1, r), eq. (64)."""
    return _on_triangles(lambda *v: triangle_vertex_momenta(system, tau, dt, ds, *v), g)


@field_function
def discrete_action(system, g, *, dt, ds, tau="cayley"):
    """S_d = Σ_j Σ_a L̄_d(△_a^j) over all triangles of the field (§3.1)."""
    return jnp.sum(_on_triangles(lambda *v: triangle_lagrangian(system, tau, dt, ds, *v), g))


def body_forces(force, g, *, dt, ds, t0=0.0):
    """f(t_j, s_a, g_a^j) at every node carrying a triangle (vertex 1), shape (rows − 1, cols − 1, r)."""
    rows, cols = g.shape[0] - 1, g.shape[1] - 1
    t = t0 + dt * jnp.arange(rows, dtype=g.dtype)
    s = ds * jnp.arange(cols, dtype=g.dtype)
    return jax.vmap(lambda tj, gj: jax.vmap(lambda sa, ga: force(tj, sa, ga))(s, gj))(t, g[:-1, :-1])


@field_function
def dcel_residual(system, g, *, dt, ds, tau="cayley", force=None, t0=0.0):
    """The Lie-group DCEL (68) with its boundary forms (69)–(71) at every node, shape (rows, cols, r):

        (μ_a^j − Ad*_{τ(Δtξ_a^{j−1})} μ_a^{j−1})/Δt + (λ_a^j − Ad*_{τ(Δsη_{a−1}^j)} λ_{a−1}^j)/Δs − f_a^j,

    where the terms of triangles outside the grid are absent. It equals −(ΔsΔt)⁻¹ times the
    left-trivialised gradient of :func:`discrete_action` (plus the forces of eq. 39, with the
    body wrench density ``force(t, s, g)`` applied at vertex 1: F̄¹ = ΔsΔt f).
    """
    G = system.group
    xi, eta = field_velocities(system, g, dt=dt, ds=ds, tau=tau)
    mu, lam = jax.vmap(jax.vmap(lambda x, e: triangle_momenta(system, tau, dt, ds, x, e)))(xi, eta)
    push = jax.vmap(jax.vmap(lambda x, m: dual_Ad(G, tau.tau(G, x), m)))
    mu_prev, lam_prev = push(dt * xi, mu), push(ds * eta, lam)
    pad = lambda x, rows, cols: jnp.pad(x, (rows, cols, (0, 0)))  # noqa: E731
    res = (pad(mu, (0, 1), (0, 1)) - pad(mu_prev, (1, 0), (0, 1))) / dt + (
        pad(lam, (0, 1), (0, 1)) - pad(lam_prev, (0, 1), (1, 0))
    ) / ds
    if force is not None:
        res = res - pad(body_forces(force, g, dt=dt, ds=ds, t0=t0), (0, 1), (0, 1))
    return res
