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

from ..lie._small import dot, matvec


N_SAMPLES = 1
RELATIVE_TOLERANCE_IN_EPS = 1000


def hessian_blocks(system, xi, n, nu, a):
    """(∂²ℓ/∂ξ², ∂²ℓ/∂ν²) at a point (M = None without additional dynamics); the cross block is
    checked by values (:func:`separability_residuals`)."""
    if nu is None:
        return jax.hessian(system.lagrangian)(xi, n, nu, a), None
    (H_xx, _), (_, H_nn) = jax.hessian(system.lagrangian, argnums=(0, 2))(xi, n, nu, a)
    return H_xx, H_nn


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


_MESSAGES = {
    "ξ odd": "a term linear in the velocities (odd in ξ)",
    "ξ": "the rotational kinetic energy is not quadratic in ξ",
    "ξ config": "the rotational kinetic energy depends on the configuration (n, a)",
    "ν odd": "a term linear in the velocities (odd in ν)",
    "ν": "the translational kinetic energy is not quadratic in ν",
    "ν config": "the translational kinetic energy depends on the configuration (n, a)",
    "ξν": "cross term ξ–ν",
}


def separability_residuals(system, J, M, diagonal):
    """[(message, residual / tolerance)]: the scene is separable where every ratio is ≤ 1.

    By values of ℓ (no derivatives: cheap enough to run at every call of a traced scene): with
    K(ξ, ν) = ½ξᵀJξ + ½νᵀMν and V(n, a) = −ℓ(0, n, 0, a), the remainder r = ℓ − K + V vanishes
    at every point exactly when ℓ is separable. At sampled velocities and configurations, r is
    split by what it isolates: ±ξ at the reference configuration (odd part: terms linear in ξ;
    even part: not quadratic), ξ at another configuration, the same for ν, and both together
    (cross terms)."""
    dtype = J.dtype
    tol = RELATIVE_TOLERANCE_IN_EPS * jnp.finfo(dtype).eps
    _, n0, _, a0 = reference_point(system, dtype)
    checks = {}
    ell = system.lagrangian

    def worst(name, value):
        checks[name] = value if name not in checks else jnp.maximum(checks[name], value)

    zeros = lambda x: None if x is None else jnp.zeros_like(x)  # noqa: E731
    for xi, n, nu, a in _samples(system, dtype):
        # Every evaluation of ℓ in one vmapped call (the scene's products batched, not repeated).
        points = {"V0": (zeros(xi), n0, zeros(nu), a0), "V": (zeros(xi), n, zeros(nu), a),
                  "ξ+": (xi, n0, zeros(nu), a0), "ξ−": (-xi, n0, zeros(nu), a0), "ξ config": (xi, n, zeros(nu), a)}
        if nu is not None:
            points.update({"ν+": (zeros(xi), n0, nu, a0), "ν−": (zeros(xi), n0, -nu, a0),
                           "ν config": (zeros(xi), n, nu, a), "ξν": (xi, n, nu, a)})
        stacked = jax.tree.map(lambda *x: jnp.stack(x), *points.values())
        values = dict(zip(points, jax.vmap(ell)(*stacked)))
        K_xi = 0.5 * dot(xi, matvec(J, xi))
        K_nu = 0.0 if nu is None else 0.5 * dot(nu, matvec(M, nu))
        kinetic = {"ξ+": K_xi, "ξ−": K_xi, "ξ config": K_xi, "ν+": K_nu, "ν−": K_nu, "ν config": K_nu, "ξν": K_xi + K_nu}
        potential = {name: -values["V" if name.endswith(("config", "ξν")) else "V0"] for name in kinetic}
        r = {name: values[name] - kinetic[name] + potential[name] for name in points if name in kinetic}
        scale = tol * (jnp.abs(K_xi) + jnp.abs(K_nu) + jnp.abs(values["V0"]) + jnp.abs(values["V"]))
        for v in ("ξ", "ν") if nu is not None else ("ξ",):
            worst(f"{v} odd", 0.5 * jnp.abs(r[f"{v}+"] - r[f"{v}−"]) / scale)
            worst(v, 0.5 * jnp.abs(r[f"{v}+"] + r[f"{v}−"]) / scale)
            worst(f"{v} config", jnp.abs(r[f"{v} config"]) / scale)
        if nu is not None:
            worst("ξν", jnp.abs(r["ξν"]) / scale)
    out = [(f"ℓ is not separable: {_MESSAGES[name]}", ratio) for name, ratio in checks.items()]
    if diagonal:
        off = J - jnp.diag(jnp.diagonal(J))
        out.append((
            "the kinetic energy is not diagonal in the standard basis of so(n), which the splitting "
            "needs on SOn (each basis element's flow is then exact); use SO3() for a full inertia on SO(3)",
            _max(off) / (tol * _max(J)),
        ))
    return out


def positive_definite(name, smallest):
    """(message, ratio) of the check that a kinetic-energy matrix is positive definite, from a
    quantity that is > 0 exactly when it is (its smallest eigenvalue or pivot)."""
    return (f"{name} is not positive definite (the kinetic energy must be)", jnp.where(smallest > 0, 0.0, 2.0))


def _at_most_one(ratio) -> bool:
    """``ratio`` ≤ 1 for a known value: compared on the host (no program to compile), or, under
    a transformation (a Lagrangian closing over a traced value), by JAX."""
    if isinstance(ratio, jax.core.Tracer):
        return bool(ratio <= 1.0)
    return float(ratio) <= 1.0


def enforce(residuals, x, *, concrete, throw=True):
    """Raise ``ValueError`` for the first failing term (``concrete``: the scene's values are known
    now); for a traced scene attach an ``eqx.error_if`` to ``x`` (``throw``) or only report.
    Returns (x, separable): separable is True, or the traced verdict for ``throw=False`` (an
    ``error_if`` costs ~0.1 ms per call on CPU: ``benchmarks/splitting_overhead.py``)."""
    separable = True
    for message, ratio in residuals:
        if concrete:
            if not _at_most_one(ratio):
                raise ValueError(f"system: {message} (residual {float(ratio):.3g} × the round-off tolerance)")
        elif throw:
            x = eqx.error_if(x, ~(ratio <= 1.0), f"system: {message}")
        else:
            separable = separable & (ratio <= 1.0)
    return x, separable
