"""Parameter fitting of the underwater vehicle (optax): observation models, Levenberg–Marquardt,
uncertainties and identifiability."""

from ._fit import FitResult as FitResult, fit as fit
from ._identifiability import identifiability as identifiability
from ._observations import Observations as Observations, synthesize as synthesize
from ._parametrisation import Parametrisation as Parametrisation
from ._levenberg_marquardt import levenberg_marquardt as levenberg_marquardt
