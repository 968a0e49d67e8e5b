"""Discrete Lagrangians, the DEP one-step map, the discrete Legendre transform and composition."""

from ._composition import composition_coefficients as composition_coefficients
from ._dep import (
    StepState as StepState,
    StepStats as StepStats,
    dep_step as dep_step,
    discrete_momenta as discrete_momenta,
    inverse_legendre as inverse_legendre,
    legendre_initial_state as legendre_initial_state,
)
from ._quadrature import discrete_lagrangian as discrete_lagrangian
