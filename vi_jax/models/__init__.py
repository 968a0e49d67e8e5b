"""Shipped scenes: each is a reduced Lagrangian through the generic engine."""

from ._rigid_body import HeavyTop as HeavyTop, RigidBody as RigidBody
from ._underwater_vehicle import UnderwaterVehicle as UnderwaterVehicle
