"""The underwater vehicle of seed 000 §4–5: G = SO(3) acting on Q = V* = R³ by rotation,
advected gravity direction a₀ = e_z (pointing down, as the paper's potential requires; spec §4).

Reduced Lagrangian, eq. (62):  ℓ = ½νᵀ(mI + M_A)ν + ½ωᵀJω + (W − B) n·a − B r·a,
with W = m·g and B = ρ|V|g (a weight, in N; spec erratum 7).
"""

import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._system import AbstractSystem, State
from ..lie import SO3, LinearAction
from ._initial import rotation_from_zxz, zxz_body_rates


def _matrix(name, value):
    arr = jnp.asarray(value, dtype=float)
    return jnp.diag(arr) if arr.ndim == 1 else arr


class UnderwaterVehicle(AbstractSystem):
    """Parameters (Table 1 defaults): ``mass`` m [kg], ``added_mass`` M_A [kg] (3×3),
    ``inertia`` J [kg m²] (body frame, 3×3), ``buoyancy`` B = ρ|V|g [N], ``gravity`` g [m/s²],
    ``buoyancy_offset`` r [m] (centre of gravity → centre of buoyancy, body frame).
    Matrix parameters also accept their diagonal."""

    mass: jnp.ndarray
    added_mass: jnp.ndarray
    inertia: jnp.ndarray
    buoyancy: jnp.ndarray
    gravity: jnp.ndarray
    buoyancy_offset: jnp.ndarray

    def __init__(
        self,
        mass=123.8,
        added_mass=(65.0, 70.0, 75.0),
        inertia=(5.46, 5.29, 5.72),
        buoyancy=1215.8,
        gravity=9.81,
        buoyancy_offset=(0.0, 0.0, -0.007),
    ):
        self.mass = val.check_positive_scalar("mass", jnp.asarray(mass, float))
        self.added_mass = _matrix("added_mass", added_mass)
        self.inertia = _matrix("inertia", inertia)
        val.as_array("added_mass", self.added_mass, (3, 3))
        val.as_array("inertia", self.inertia, (3, 3))
        val.check_spd("inertia", self.inertia)
        if val.is_concrete(self.added_mass):
            val.check_spd("added_mass + mass·I", np.asarray(self.added_mass) + np.asarray(self.mass) * np.eye(3))
        self.buoyancy = val.check_finite("buoyancy", jnp.asarray(buoyancy, float))
        val.as_array("buoyancy", self.buoyancy, ())
        self.gravity = val.check_positive_scalar("gravity", jnp.asarray(gravity, float))
        self.buoyancy_offset = val.check_finite(
            "buoyancy_offset", val.as_array("buoyancy_offset", jnp.asarray(buoyancy_offset, float), (3,))
        )

    @property
    def group(self):
        return SO3()

    @property
    def advected_action(self):
        return LinearAction(SO3())

    @property
    def advected_reference(self):
        return np.array([0.0, 0.0, 1.0])

    @property
    def configuration_action(self):
        return LinearAction(SO3())

    def lagrangian(self, xi, n, nu, a):
        weight = self.mass * self.gravity
        mass_matrix = self.mass * jnp.eye(3, dtype=nu.dtype) + self.added_mass
        kinetic = 0.5 * nu @ mass_matrix @ nu + 0.5 * xi @ self.inertia @ xi
        return kinetic + (weight - self.buoyancy) * (n @ a) - self.buoyancy * (self.buoyancy_offset @ a)

    def initial_state(self, *, R0=None, q0=None, omega0=None, v0=None) -> State:
        """Table 2: ZXZ Euler angles (2π, 0, 2π) with rates 10°/s each, q₀ = (0, 0, 1) m,
        v₀ = (0.1, 0.1, 0.8) m/s in the space frame. Keywords override each piece."""
        angles = (2 * jnp.pi, 0.0, 2 * jnp.pi)
        rates = (jnp.pi / 18, jnp.pi / 18, jnp.pi / 18)
        R0 = jnp.asarray(rotation_from_zxz(*angles)) if R0 is None else val.as_array("R0", R0, (3, 3))
        omega0 = jnp.asarray(zxz_body_rates(angles, rates)) if omega0 is None else val.as_array("omega0", omega0, (3,))
        q0 = jnp.array([0.0, 0.0, 1.0]) if q0 is None else val.as_array("q0", q0, (3,))
        v0 = jnp.array([0.1, 0.1, 0.8]) if v0 is None else val.as_array("v0", v0, (3,))
        for name, value in (("R0", R0), ("omega0", omega0), ("q0", q0), ("v0", v0)):
            val.check_finite(name, value)
        val.check_on_group("R0", SO3(), R0)
        return State(g=R0, xi=omega0, q=q0, qdot=v0)
