"""The continuous Euler–Poincaré equations with advected parameters and additional dynamics
(seed 000 eqs. 12–13, 20–21), built by autodiff from the same reduced Lagrangian a scene has,
with the reconstruction equations, as a diffrax ``ODETerm``.

State y = (g, ξ, q, ν) (q, ν are None without additional dynamics). With μ = ℓ_ξ, p = ℓ_ν:

  μ̇ = ad*_ξ μ + ℓ_a◇a + ℓ_n◇n + ℓ_ν◇ν,   ṗ = ℓ_n + ρ'_Q(ξ)ᵀp,
  ṅ = ν − ρ'_Q(ξ)n,   ȧ = −ρ'_V(ξ)a,   ġ = gξ̂,   q̇ = ρ_Q(g)ν,

solved for (ξ̇, ν̇) in velocity form: H·[ξ̇; ν̇] = [μ̇; ṗ] − (∂_n∇ℓ)ṅ − (∂_a∇ℓ)ȧ with H the Hessian
of ℓ in (ξ, ν) (ℓ must be regular). The energy and Kelvin–Noether quantity (eqs. 27–28) are
the same functions the discrete solutions report.
"""

import diffrax
import jax
import jax.numpy as jnp

from ._diagnostics import kelvin_noether as _kelvin_noether, kelvin_noether_scale as _kelvin_noether_scale
from .solvers import dense_solve
from ._system import AbstractSystem, State


def _reduced(system, g, q):
    return system.body_configuration(g, q), system.body_advected(g)


def _velocities(system, xi, nu):
    return xi if nu is None else jnp.concatenate([xi, nu])


def _momenta_flat(system, z, n, a):
    r = system.group.dim
    xi, nu = (z[:r], z[r:]) if system.has_additional else (z, None)
    mu, p = system.momenta(xi, n, nu, a)
    return mu if p is None else jnp.concatenate([mu, p])


def time_derivative(system: AbstractSystem, y):
    """dy/dt for y = (g, ξ, q, ν)."""
    g, xi, q, nu = y
    G = system.group
    n, a = _reduced(system, g, q)
    ell_xi, ell_n, ell_nu, ell_a = jax.grad(system.lagrangian, argnums=(0, 1, 2, 3))(xi, n, nu, a)
    mu_dot = G.ad_dual(xi, ell_xi)
    n_dot = a_dot = None
    q_dot = None
    if system.has_advected:
        V = system.advected_action
        mu_dot = mu_dot + V.diamond(ell_a, a)
        a_dot = -V.infinitesimal(xi, a)
    if system.has_additional:
        Q = system.configuration_action
        mu_dot = mu_dot + Q.diamond(ell_n, n) + Q.diamond(ell_nu, nu)
        p_dot = ell_n + Q.infinitesimal_transpose(xi, ell_nu)
        n_dot = nu - Q.infinitesimal(xi, n)
        q_dot = Q.act(g, nu)
        rhs = jnp.concatenate([mu_dot, p_dot])
    else:
        rhs = mu_dot
    z = _velocities(system, xi, nu)
    hessian = jax.jacfwd(_momenta_flat, argnums=1)(system, z, n, a)
    if n_dot is not None or a_dot is not None:
        zeros = lambda x: None if x is None else jnp.zeros_like(x)  # noqa: E731
        _, drift = jax.jvp(
            lambda n_, a_: _momenta_flat(system, z, n_, a_),
            (n, a),
            (zeros(n) if n_dot is None else n_dot, zeros(a) if a_dot is None else a_dot),
        )
        rhs = rhs - drift
    z_dot = dense_solve(hessian, rhs)
    r = G.dim
    xi_dot, nu_dot = (z_dot[:r], z_dot[r:]) if system.has_additional else (z_dot, None)
    return (g @ G.hat(xi), xi_dot, q_dot, nu_dot)


def vector_field(system: AbstractSystem) -> diffrax.ODETerm:
    """The continuous EP equations as a diffrax term on y = (g, ξ, q, ν)."""
    return diffrax.ODETerm(lambda t, y, args: time_derivative(system, y))


def initial_state(system: AbstractSystem, x0: State):
    """y₀ = (g, ξ, q, ν) from the continuous initial data (ν = ρ_Q(g)⁻¹q̇ in the body frame)."""
    nu = None
    if system.has_additional:
        nu = system.configuration_action.act_inverse(x0.g, x0.qdot)
    return (x0.g, x0.xi, x0.q, nu)


def energy(system: AbstractSystem, y):
    """E = ⟨ℓ_ξ, ξ⟩ + ⟨ℓ_ν, ν⟩ − ℓ at y (works on a leading time axis too)."""
    g, xi, q, nu = y
    if g.ndim == 3:
        return jax.vmap(lambda *s: energy(system, s))(g, xi, q, nu)
    n, a = _reduced(system, g, q)
    return system.energy(xi, n, nu, a)


def kelvin_noether_scale(system: AbstractSystem, y):
    """|μ| + |p||n|: the size of the terms that cancel in the Kelvin–Noether quantity."""
    g, xi, q, nu = y
    if g.ndim == 3:
        return jax.vmap(lambda *s: kelvin_noether_scale(system, s))(g, xi, q, nu)
    n, a = _reduced(system, g, q)
    mu, p = system.momenta(xi, n, nu, a)
    return _kelvin_noether_scale(system, g, q, mu, p)


def kelvin_noether(system: AbstractSystem, y):
    """I = ⟨ζ, Ad*_{g⁻¹}(μ − p◇n)⟩ for ζ in the isotropy algebra of a₀ (eqs. 27–28)."""
    g, xi, q, nu = y
    if g.ndim == 3:
        return jax.vmap(lambda *s: kelvin_noether(system, s))(g, xi, q, nu)
    n, a = _reduced(system, g, q)
    mu, p = system.momenta(xi, n, nu, a)
    value = _kelvin_noether(system, g, q, mu, p)
    return value[0] if value.shape[-1] == 1 else value


def solve(system: AbstractSystem, x0: State, t1, *, solver=None, rtol=1e-10, atol=1e-10, saveat=None, max_steps=1_000_000, dt0=None):
    """Convenience: integrate the continuous equations with diffrax (default Dopri8 + PID)."""
    return diffrax.diffeqsolve(
        vector_field(system), solver or diffrax.Dopri8(), 0.0, t1, dt0, initial_state(system, x0),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        saveat=saveat or diffrax.SaveAt(t1=True), max_steps=max_steps,
    )
