"""Parameter fitting of the underwater vehicle (optax): telemetry and observation models,
multiple shooting, Levenberg–Marquardt, robust losses, uncertainties and identifiability."""

from ._fit import FitResult as FitResult, fit as fit
from ._identifiability import channel_report as channel_report, identifiability as identifiability
from ._observations import Observations as Observations, synthesize as synthesize
from ._parametrisation import Parametrisation as Parametrisation
from ._levenberg_marquardt import levenberg_marquardt as levenberg_marquardt
from ._telemetry import Telemetry as Telemetry, synthesize_telemetry as synthesize_telemetry
from ._csv import read_telemetry as read_telemetry, write_telemetry as write_telemetry
