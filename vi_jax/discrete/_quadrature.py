"""Discrete Lagrangians ℓ̃(ξ, n, ν, a) from a continuous reduced Lagrangian, in the velocity
form ν = (s − n)/h of the seed 000 spec §2 (ℓ̃(ξ,n,ν,a) = ℓ^d(ξ, n, n + hν, a)).

- ``"left"``: ℓ̃ = ℓ(ξ, n, ν, a), the left-point rule; for the vehicle this is exactly the
  paper's eq. (71). First order.
- ``"trapezoid"``: the average of ℓ in the body frames at both ends of the step, with
  Λ = τ(hξ): ½[ℓ(ξ, n, ν, a) + ℓ(ξ, Λ⁻¹(n + hν), Λ⁻¹ν, Λ⁻¹a)]. G-invariant and self-adjoint,
  hence second order (seed 000 spec §5, "minimal fix").
"""

RULES = ("left", "trapezoid")


def discrete_lagrangian(system, tau, rule, h, xi, n, nu, a):
    ell = system.lagrangian(xi, n, nu, a)
    if rule == "left":
        return ell
    if rule != "trapezoid":
        raise ValueError(f"rule: expected one of {RULES}, got {rule!r}")
    lam = tau.tau(system.group, h * xi)
    n1 = nu1 = a1 = None
    if n is not None:
        Q = system.configuration_action
        n1 = Q.act_inverse(lam, n + h * nu)
        nu1 = Q.act_inverse(lam, nu)
    if a is not None:
        a1 = system.advected_action.act_inverse(lam, a)
    return 0.5 * (ell + system.lagrangian(xi, n1, nu1, a1))
