"""Is ℓ(ξ, n, ν, a) = ½ξᵀJξ + ½νᵀMν − V(n, a) with constant J, M (what the splitting scheme
needs)? Checked at sampled points, to round-off, term by term, so that the error names the term
that fails.

Tolerance: every quantity compared is a sum of O(d²) products of the scene's own numbers (the
Hessians of a quadratic form are exact up to the rounding of those products), so a separable ℓ
agrees to a few ε of the size of its terms; 1000ε leaves a wide margin for that and for any
user arithmetic, while a non-separable term must be smaller than 1000ε of the energy to pass,
i.e. below what the working precision resolves anyway.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


N_SAMPLES = 1
RELATIVE_TOLERANCE_IN_EPS = 1000


def hessian_blocks(system, xi, n, nu, a):
    """(∂²ℓ/∂ξ², ∂²ℓ/∂ν², ∂²ℓ/∂ξ∂ν) at a point (None blocks without additional dynamics)."""
    if nu is None:
        return jax.hessian(system.lagrangian)(xi, n, nu, a), None, None
    (H_xx, H_xn), (_, H_nn) = jax.hessian(system.lagrangian, argnums=(0, 2))(xi, n, nu, a)
    return H_xx, H_nn, H_xn


def reference_point(system, dtype):
    """(ξ, n, ν, a) = (0, 0, 0, a₀): g = identity, q = 0."""
    G = system.group
    g = jnp.eye(G.matrix_size, dtype=dtype)
    q = jnp.zeros(G.matrix_size, dtype) if system.has_additional else None
    nu = jnp.zeros(G.matrix_size, dtype) if system.has_additional else None
    return jnp.zeros(G.dim, dtype), system.body_configuration(g, q), nu, system.body_advected(g)


def _samples(system, dtype):
    """(ξ, n, ν, a) at random velocities and configurations (fixed seed, so the check is
    reproducible): g = exp of a random algebra element, q random."""
    G = system.group
    rng = np.random.default_rng(20260512)
    for _ in range(N_SAMPLES):
        xi = jnp.asarray(rng.normal(size=G.dim), dtype)
        g = G.exp(jnp.asarray(rng.normal(size=G.dim), dtype))
        q = jnp.asarray(rng.normal(size=G.matrix_size), dtype) if system.has_additional else None
        nu = jnp.asarray(rng.normal(size=G.matrix_size), dtype) if system.has_additional else None
        yield xi, system.body_configuration(g, q), nu, system.body_advected(g)


def _max(x):
    return jnp.max(jnp.abs(x))


def separability_residuals(system, J, M, diagonal):
    """[(message, residual / tolerance)]: the scene is separable where every ratio is ≤ 1."""
    dtype = J.dtype
    tol = RELATIVE_TOLERANCE_IN_EPS * jnp.finfo(dtype).eps
    _, n0, _, a0 = reference_point(system, dtype)
    size = _max(J) + (0.0 if M is None else _max(M))
    checks = {}

    def worst(name, value):
        checks[name] = value if name not in checks else jnp.maximum(checks[name], value)

    def potential(n, a):
        return -system.lagrangian(jnp.zeros(system.group.dim, dtype), n, None if n is None else jnp.zeros_like(n), a)

    for xi, n, nu, a in _samples(system, dtype):
        J_v, M_v, C_v = hessian_blocks(system, xi, n0, nu, a0)  # other velocities
        J_c, M_c, C_c = hessian_blocks(system, jnp.zeros_like(xi), n, None if nu is None else jnp.zeros_like(nu), a)
        worst("ξ", _max(J_v - J) / (tol * _max(J)))
        worst("ξ config", _max(J_c - J) / (tol * _max(J)))
        if M is not None:
            worst("ν", _max(M_v - M) / (tol * _max(M)))
            worst("ν config", _max(M_c - M) / (tol * _max(M)))
            worst("ξν", jnp.maximum(_max(C_v), _max(C_c)) / (tol * size))
        kinetic = 0.5 * xi @ J @ xi + (0.0 if nu is None else 0.5 * nu @ M @ nu)
        V = potential(n, a)
        ell = system.lagrangian(xi, n, nu, a)
        worst("value", jnp.abs(ell - (kinetic - V)) / (tol * (jnp.abs(kinetic) + jnp.abs(V) + jnp.abs(ell))))
    messages = {
        "ξ": "the rotational kinetic energy is not quadratic in ξ (∂²ℓ/∂ξ² depends on the velocities)",
        "ξ config": "the rotational kinetic energy depends on the configuration (∂²ℓ/∂ξ² depends on n, a)",
        "ν": "the translational kinetic energy is not quadratic in ν (∂²ℓ/∂ν² depends on the velocities)",
        "ν config": "the translational kinetic energy depends on the configuration (∂²ℓ/∂ν² depends on n, a)",
        "ξν": "cross term ξ–ν (∂²ℓ/∂ξ∂ν ≠ 0)",
        "value": "ℓ ≠ ½ξᵀJξ + ½νᵀMν − V(n, a) at sampled points (a term linear in the velocities?)",
    }
    out = [(f"ℓ is not separable: {messages[name]}", ratio) for name, ratio in checks.items()]
    if diagonal:
        off = J - jnp.diag(jnp.diagonal(J))
        out.append((
            "the kinetic energy is not diagonal in the standard basis of so(n), which the splitting "
            "needs on SOn (each basis element's flow is then exact); use SO3() for a full inertia on SO(3)",
            _max(off) / (tol * _max(J)),
        ))
    for name, mat in (("J = ∂²ℓ/∂ξ²", J), ("M = ∂²ℓ/∂ν²", M)):
        if mat is not None:
            # ≤ 0 when positive definite: the smallest eigenvalue relative to the largest.
            w = jnp.linalg.eigvalsh(0.5 * (mat + mat.T))
            out.append((f"{name} is not positive definite (the kinetic energy must be)", jnp.where(w[0] > 0, 0.0, 2.0)))
    return out


def enforce(residuals, x, *, concrete, throw=True):
    """Raise ``ValueError`` for the first failing term (``concrete``: the scene's values are known
    now); for a traced scene attach an ``eqx.error_if`` to ``x`` (``throw``) or only report.
    Returns (x, separable): separable is True, or the traced verdict for ``throw=False`` (an
    ``error_if`` costs ~0.1 ms per call on CPU: ``benchmarks/splitting_overhead.py``)."""
    separable = True
    for message, ratio in residuals:
        if concrete:
            if not bool(ratio <= 1.0):
                raise ValueError(f"system: {message} (residual {float(ratio):.3g} × the round-off tolerance)")
        elif throw:
            x = eqx.error_if(x, ~(ratio <= 1.0), f"system: {message}")
        else:
            separable = separable & (ratio <= 1.0)
    return x, separable
