"""Lie groups, group difference maps (Cayley, exp) and linear actions."""

from ._actions import LinearAction as LinearAction
from ._base import AbstractMatrixGroup as AbstractMatrixGroup
from ._difference_maps import (
    AbstractDifferenceMap as AbstractDifferenceMap,
    Cayley as Cayley,
    Exp as Exp,
    difference_map as difference_map,
)
from ._se3 import SE3 as SE3
from ._so3 import SO3 as SO3
from ._son import Rn as Rn, SOn as SOn
