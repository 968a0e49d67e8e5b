"""The engine: any scene and scheme scanned over time (``simulate``), ensembles with the members
on a vectorised axis (``ensemble``), and the backend plans (XLA:CPU loop fusion)."""

from ._cpu_tuning import enable_fast_cpu_loops as enable_fast_cpu_loops
from ._ensemble import ensemble as ensemble, member_converged as member_converged, vary as vary
from ._placement import PerformanceWarning as PerformanceWarning
from ._simulate import NewtonFailure as NewtonFailure, Solution as Solution, simulate as simulate
