"""Shipped scenes: each is a reduced Lagrangian through the generic engine (the beam through the
multisymplectic engine), written like the paper's section: parameters, reduced Lagrangian,
initial conditions.

``clebsch`` and ``suris`` are stand-alone integrators (``vi_jax.integrators``), re-exported here
where they were first published."""

from ._beam import GeometricallyExactBeam as GeometricallyExactBeam
from ._rigid_body import HeavyTop as HeavyTop, RigidBody as RigidBody
from ._underwater_vehicle import UnderwaterVehicle as UnderwaterVehicle
from ..integrators import clebsch as clebsch, suris as suris  # noqa: E402  (after the scenes they use)
