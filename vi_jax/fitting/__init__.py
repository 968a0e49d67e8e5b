"""Parameter fitting of the underwater vehicle (optax): observation models, Levenberg–Marquardt,
uncertainties and identifiability."""

from ._fit import (
    FitResult as FitResult,
    Observations as Observations,
    Parametrisation as Parametrisation,
    fit as fit,
    identifiability as identifiability,
    synthesize as synthesize,
)
from ._levenberg_marquardt import levenberg_marquardt as levenberg_marquardt
