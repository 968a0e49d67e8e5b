"""vi_jax: differentiable Lie-group variational integrators in JAX."""

from . import continuous as continuous, discrete as discrete, lie as lie, models as models, multisymplectic as multisymplectic
from ._cpu_tuning import enable_fast_cpu_loops as enable_fast_cpu_loops
from ._diagnostics import (
    group_constraint_residual as group_constraint_residual,
    kelvin_noether as kelvin_noether,
)
from ._ensemble import ensemble as ensemble, member_converged as member_converged, vary as vary
from ._fit import (
    FitResult as FitResult,
    Observations as Observations,
    Parametrisation as Parametrisation,
    fit as fit,
    identifiability as identifiability,
    levenberg_marquardt as levenberg_marquardt,
    synthesize as synthesize,
)
from ._simulate import NewtonFailure as NewtonFailure, Solution as Solution, simulate as simulate
from ._system import AbstractSystem as AbstractSystem, State as State, System as System

__version__ = "0.1.0"
