"""Taylor-safe scalar functions of θ² for the exponential and its tangent maps.

Each function takes ``theta2 = x·x`` (never ``|x|``, whose derivative is singular at 0) and
switches to a series below ``SMALL``; the double-``where`` keeps both branches' values *and*
gradients finite (seed 000 spec §5).
"""

import jax.numpy as jnp

SMALL = 1e-2  # θ² below which the series is used (relative error ≤ 3e-15 there)


def _safe(theta2, small_branch, closed_form):
    is_small = theta2 < SMALL
    safe_theta2 = jnp.where(is_small, jnp.ones_like(theta2), theta2)
    return jnp.where(is_small, small_branch(theta2), closed_form(safe_theta2))


def sinc(theta2):
    """sin θ / θ."""
    return _safe(
        theta2,
        lambda t: 1 - t / 6 + t**2 / 120 - t**3 / 5040,
        lambda t: jnp.sin(jnp.sqrt(t)) / jnp.sqrt(t),
    )


def one_minus_cos_over_t2(theta2):
    """(1 − cos θ) / θ²."""
    return _safe(
        theta2,
        lambda t: 0.5 - t / 24 + t**2 / 720 - t**3 / 40320,
        lambda t: (1 - jnp.cos(jnp.sqrt(t))) / t,
    )


def t_minus_sin_over_t3(theta2):
    """(θ − sin θ) / θ³."""
    return _safe(
        theta2,
        lambda t: 1 / 6 - t / 120 + t**2 / 5040 - t**3 / 362880,
        lambda t: (jnp.sqrt(t) - jnp.sin(jnp.sqrt(t))) / (t * jnp.sqrt(t)),
    )


def dexp_inv_alpha(theta2):
    """α(θ) = (1 − (θ/2)cot(θ/2)) / θ², seed 000 eq. (93); poles at θ = 2πk, k ≠ 0."""
    return _safe(
        theta2,
        lambda t: 1 / 12 + t / 720 + t**2 / 30240 + t**3 / 1209600,
        lambda t: (1 - 0.5 * jnp.sqrt(t) / jnp.tan(0.5 * jnp.sqrt(t))) / t,
    )
