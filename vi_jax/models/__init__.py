"""Shipped scenes: each is a reduced Lagrangian through the generic engine (the beam through the
multisymplectic engine), plus the Clebsch rigid-body integrator (``clebsch``) and Suris's explicit
integrable maps (``suris``)."""

from . import clebsch as clebsch, suris as suris
from ._beam import GeometricallyExactBeam as GeometricallyExactBeam
from ._rigid_body import HeavyTop as HeavyTop, RigidBody as RigidBody
from ._underwater_vehicle import UnderwaterVehicle as UnderwaterVehicle
