"""Symmetric compositions of the second-order symmetric step Φ_h (trapezoid rule):
Φ_{γ_s h} ∘ … ∘ Φ_{γ_1 h} is again a variational integrator (a composition of discrete
Lagrangian flows), of higher order.

- order 4: the "triple jump" γ = (γ₁, 1 − 2γ₁, γ₁), γ₁ = 1/(2 − 2^{1/3}) (Yoshida 1990;
  Hairer, Lubich & Wanner, *Geometric Numerical Integration*, 2nd ed., §II.4, eq. 4.4).
- order 6: the 9-stage symmetric composition of Kahan & Li 1997 (HLW §V.3.2, eq. 3.12, "p6 s9").
"""

_Y1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
_TRIPLE_JUMP = (_Y1, 1.0 - 2.0 * _Y1, _Y1)
_KAHAN_LI_6_9_HALF = (
    0.39216144400731413928,
    0.33259913678935943860,
    -0.70624617255763935981,
    0.082213596293550800230,
)
_KAHAN_LI_6_9 = (
    *_KAHAN_LI_6_9_HALF,
    1.0 - 2.0 * sum(_KAHAN_LI_6_9_HALF),
    *reversed(_KAHAN_LI_6_9_HALF),
)

ORDERS = (1, 2, 4, 6)


def composition_coefficients(order: int):
    """(quadrature rule, sub-step fractions γ_i) for ``order`` ∈ {1, 2, 4, 6}."""
    if order == 1:
        return "left", (1.0,)
    if order == 2:
        return "trapezoid", (1.0,)
    if order == 4:
        return "trapezoid", _TRIPLE_JUMP
    if order == 6:
        return "trapezoid", _KAHAN_LI_6_9
    raise ValueError(f"order: expected one of {ORDERS}, got {order!r}")
