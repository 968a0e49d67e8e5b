"""Robust losses as residual transforms: r ↦ sign(r)·√(2ρ(r)), so that ½Σr̃² = Σρ(r) and
Gauss–Newton / Levenberg–Marquardt on r̃ minimises the robust loss (Triggs et al., "Bundle
adjustment — a modern synthesis", 2000, §4.3: the square-root form of an M-estimator).

On whitened residuals r (units of σ): ``"squared"`` ρ = r²/2; ``"huber"`` quadratic up to
``HUBER_K`` σ, linear beyond; ``"cauchy"`` ρ = c²/2·log(1 + (r/c)²) with c = ``CAUCHY_C``
(both constants give 95 % efficiency on Gaussian noise: Huber 1964, Holland & Welsch 1977).
Each is r·w(r) with w smooth and w(0) = 1, written with the double-``where`` trick so that
values and gradients are finite at r = 0.
"""

import jax
import jax.numpy as jnp

from .. import _validation as val

LOSSES = ("squared", "huber", "cauchy")

HUBER_K = 1.345

CAUCHY_C = 2.3849


def _squared(r):
    return r


def _huber(r):
    inside = jnp.abs(r) <= HUBER_K
    safe = jnp.where(inside, 1.0, jnp.abs(r))
    return r * jnp.where(inside, 1.0, jnp.sqrt(2 * HUBER_K * safe - HUBER_K**2) / safe)


def _cauchy(r):
    u2 = (r / CAUCHY_C) ** 2
    small = u2 < 1e-8
    safe = jnp.where(small, 1.0, u2)
    return r * jnp.where(small, 1 - u2 / 4, jnp.sqrt(jnp.log1p(safe) / safe))


_TRANSFORMS = (_squared, _huber, _cauchy)


def loss_index(loss) -> int:
    """The position of the loss named ``loss`` in ``LOSSES`` (a ``ValueError`` for another name)."""
    return LOSSES.index(val.check_choice("loss", loss, LOSSES))


def robust_residuals(r, loss):
    """r̃ = r·w(r) for the loss ``loss`` (see the module docstring): a name of ``LOSSES``, or its
    index there as an integer array, which may be traced (the fit's programs take it so: one
    program serves every loss)."""
    if isinstance(loss, str):
        return _TRANSFORMS[loss_index(loss)](r)
    return jax.lax.switch(loss, _TRANSFORMS, r)
