"""Shipped scenes: each is a reduced Lagrangian through the generic engine, plus Suris's
explicit integrable maps (``suris``)."""

from . import clebsch as clebsch, suris as suris
from ._rigid_body import HeavyTop as HeavyTop, RigidBody as RigidBody
from ._underwater_vehicle import UnderwaterVehicle as UnderwaterVehicle
