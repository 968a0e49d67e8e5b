"""Multisymplectic Lie-group variational integrators on a 1+1 spacetime grid of triangles
(seed 003, Demoures–Gay-Balmaz–Ratiu): discrete Lagrangian and momenta, the time and space
marches, momentum maps and energies, and checks of (multi)symplecticity."""

from ._lagrangian import (
    AbstractCovariantSystem as AbstractCovariantSystem,
    CovariantSystem as CovariantSystem,
    dcel_residual as dcel_residual,
    discrete_action as discrete_action,
    field_velocities as field_velocities,
    vertex_momenta as vertex_momenta,
)
from ._march import MarchFailure as MarchFailure
from ._noether import (
    covariant_momentum as covariant_momentum,
    space_energy as space_energy,
    space_momentum_map as space_momentum_map,
    time_energy as time_energy,
    time_momentum_map as time_momentum_map,
    triangle_momentum_maps as triangle_momentum_maps,
)
from ._space import SpaceMarch as SpaceMarch, space_march as space_march
from ._space_dirichlet import space_march_dirichlet as space_march_dirichlet
from ._symplectic import (
    field_variation as field_variation,
    multisymplectic_formula as multisymplectic_formula,
    space_map_symplecticity as space_map_symplecticity,
    space_march_jvp as space_march_jvp,
    symplectic_form as symplectic_form,
    time_map_symplecticity as time_map_symplecticity,
    time_march_jvp as time_march_jvp,
)
from ._time import TimeMarch as TimeMarch, time_march as time_march
