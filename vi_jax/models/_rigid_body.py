"""The free rigid body and the heavy top as reduced Lagrangians on SO(3).

Free rigid body: ℓ(Ω) = ½ΩᵀIΩ (no advected parameter, no additional dynamics).
Heavy top: ℓ(Ω, Γ) = ½ΩᵀIΩ − m g χ·Γ with the advected body-frame direction Γ = Rᵀe₃
(gravity along −e₃, χ the centre of mass in the body frame).
"""

import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._system import AbstractSystem, State
from ..lie import SO3, LinearAction


def _inertia(value):
    arr = jnp.asarray(value, dtype=float)
    arr = jnp.diag(arr) if arr.ndim == 1 else arr
    val.as_array("inertia", arr, (3, 3))
    return val.check_spd("inertia", arr)


class RigidBody(AbstractSystem):
    """Free rigid body with body-frame inertia ``inertia`` (3×3 or its diagonal)."""

    inertia: jnp.ndarray

    def __init__(self, inertia=(0.5, 0.6, 1.0)):
        self.inertia = _inertia(inertia)

    @property
    def group(self):
        return SO3()

    def lagrangian(self, xi, n, nu, a):
        return 0.5 * xi @ self.inertia @ xi

    def initial_state(self, *, R0=None, omega0=(1.0, 0.5, -0.3)) -> State:
        R0 = jnp.eye(3) if R0 is None else val.as_array("R0", R0, (3, 3))
        val.check_on_group("R0", SO3(), R0)
        return State(g=R0, xi=val.check_finite("omega0", val.as_array("omega0", omega0, (3,))))


class HeavyTop(AbstractSystem):
    """Heavy top: ``inertia`` about the fixed point, ``mass``, ``gravity`` and centre of mass
    ``center_of_mass`` χ (body frame)."""

    inertia: jnp.ndarray
    mass: jnp.ndarray
    gravity: jnp.ndarray
    center_of_mass: jnp.ndarray

    def __init__(self, inertia=(1.0, 1.0, 0.4), mass=1.0, gravity=9.81, center_of_mass=(0.0, 0.0, 0.5)):
        self.inertia = _inertia(inertia)
        self.mass = val.check_positive_scalar("mass", jnp.asarray(mass, float))
        self.gravity = val.check_positive_scalar("gravity", jnp.asarray(gravity, float))
        self.center_of_mass = val.check_finite(
            "center_of_mass", val.as_array("center_of_mass", jnp.asarray(center_of_mass, float), (3,))
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

    def lagrangian(self, xi, n, nu, a):
        return 0.5 * xi @ self.inertia @ xi - self.mass * self.gravity * (self.center_of_mass @ a)

    def initial_state(self, *, R0=None, omega0=(0.3, -0.2, 6.0)) -> State:
        """Default: tilted by 0.3 rad about e₁, spinning fast about its symmetry axis."""
        if R0 is None:
            c, s = jnp.cos(0.3), jnp.sin(0.3)
            R0 = jnp.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        R0 = val.as_array("R0", R0, (3, 3))
        val.check_on_group("R0", SO3(), R0)
        return State(g=R0, xi=val.check_finite("omega0", val.as_array("omega0", omega0, (3,))))
