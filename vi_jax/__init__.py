"""vi_jax: differentiable Lie-group variational integrators in JAX."""

from . import (
    continuous as continuous,
    discrete as discrete,
    fitting as fitting,
    integrators as integrators,
    lie as lie,
    models as models,
    multisymplectic as multisymplectic,
)
from ._accuracy import AccuracyWarning as AccuracyWarning
from ._diagnostics import (
    group_constraint_residual as group_constraint_residual,
    kelvin_noether as kelvin_noether,
)
from ._system import AbstractSystem as AbstractSystem, State as State, System as System
from .engine import (
    NewtonFailure as NewtonFailure,
    PerformanceWarning as PerformanceWarning,
    Solution as Solution,
    enable_fast_cpu_loops as enable_fast_cpu_loops,
    ensemble as ensemble,
    member_converged as member_converged,
    simulate as simulate,
    vary as vary,
)
from .fitting import (
    FitResult as FitResult,
    Observations as Observations,
    Parametrisation as Parametrisation,
    Telemetry as Telemetry,
    fit as fit,
    identifiability as identifiability,
    levenberg_marquardt as levenberg_marquardt,
    read_telemetry as read_telemetry,
    synthesize as synthesize,
    synthesize_telemetry as synthesize_telemetry,
    write_telemetry as write_telemetry,
)

__version__ = "0.1.0"
