"""Stand-alone integrators that are not the DEP engine: the Clebsch variational integrator of the
rigid body (seed 002) and Suris's explicit integrable maps of tops (seed 004)."""

from . import clebsch as clebsch, suris as suris
