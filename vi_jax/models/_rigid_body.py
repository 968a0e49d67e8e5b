"""The free rigid body and the heavy top as reduced Lagrangians on SO(3) or SO(n), n ≥ 3.

Free rigid body: ℓ(Ω) = ½⟨Ω, 𝕀Ω⟩ with a symmetric positive inertia operator 𝕀 on the algebra
coordinates. On SO(n) the generalised rigid body has 𝕀Ω = JΩ + ΩJ for a symmetric mass matrix J
(seed 004 §2: M_jk = (J_j + J_k)Ω_jk for diagonal J); on SO(3) this is the inertia
I = tr(J)·1 − J, i.e. I₁ = J₂ + J₃ etc.
Heavy top: ℓ(Ω, Γ) = ½⟨Ω, 𝕀Ω⟩ − m g χ·Γ with the advected body-frame direction Γ = Rᵀe_n
(gravity along −e_n, χ the centre of mass in the body frame); seed 004 §2 with P = m g|χ|Γ,
A = χ/|χ|. A symmetric J = (α/2, …, α/2, 1 − α/2) with χ ∥ e_n is the Lagrange top.

``group``: ``SO3()`` (default; cross-product coordinates) or ``SOn(n)`` (coordinates x_ij, i < j;
for n = 3, (x₀₁, x₀₂, x₁₂) = (x₃, −x₂, x₁) of the SO3 convention).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._system import AbstractSystem, State
from ..lie import SO3, AbstractMatrixGroup, LinearAction, SOn


def _group(group):
    if group is None:
        return SO3()
    if isinstance(group, SO3) or (isinstance(group, SOn) and group.n >= 3):
        return group
    raise ValueError(f"group: expected vi_jax.lie.SO3() or vi_jax.lie.SOn(n) with n ≥ 3, got {group!r}")


def inertia_from_mass_matrix(group: AbstractMatrixGroup, mass_matrix):
    """Matrix of the operator x ↦ vee(J x̂ + x̂ J) on the algebra coordinates of ``group``
    (J: n×n symmetric, or its diagonal)."""
    n = group.matrix_size
    J = val.as_array("mass_matrix", jnp.asarray(mass_matrix, float))
    J = jnp.diag(J) if J.ndim == 1 else J
    val.as_array("mass_matrix", J, (n, n))
    val.check_finite("mass_matrix", J)
    if val.is_concrete(J) and not np.allclose(J, J.T, rtol=1e-12, atol=1e-14):
        raise ValueError(f"mass_matrix: expected a symmetric {n}×{n} matrix or its diagonal, got {J}")

    def apply(x):
        X = group.hat(x)
        return group.vee(J @ X + X @ J)

    return jax.jacfwd(apply)(jnp.zeros(group.dim, J.dtype))


def _inertia(group, inertia, mass_matrix, default):
    """The r×r inertia operator from ``inertia`` (r×r or its diagonal) or ``mass_matrix``."""
    if inertia is not None and mass_matrix is not None:
        raise ValueError("inertia, mass_matrix: expected at most one of them, got both")
    if mass_matrix is not None:
        arr = inertia_from_mass_matrix(group, mass_matrix)
        name = "inertia from mass_matrix (J_i + J_j > 0 required)"
    else:
        arr = jnp.asarray(default if inertia is None else inertia, dtype=float)
        arr = jnp.diag(arr) if arr.ndim == 1 else arr
        name = "inertia"
    val.as_array(name, arr, (group.dim, group.dim))
    return val.check_spd(name, arr)


@eqx.filter_jit  # one program to compile, not one per operation (built from constants)
def embed_so3(group, R=None, omega=None):
    """An SO(3) attitude R and rotation vector ω (cross-product convention) acting on the last
    three axes of R^n, as (g, ξ) of ``group``; identity and zero where not given."""
    n = group.matrix_size
    g = jnp.eye(n) if R is None else jnp.eye(n).at[n - 3 :, n - 3 :].set(jnp.asarray(R, float))
    xi = jnp.zeros(group.dim)
    if omega is not None:
        X = jnp.zeros((n, n)).at[n - 3 :, n - 3 :].set(SO3().hat(jnp.asarray(omega, float)))
        xi = group.vee(X)
    return g, xi


def _initial_state(group, R0, omega0, R0_default, omega0_default) -> State:
    g_default, xi_default = embed_so3(group, R0_default, omega0_default)
    n, r = group.matrix_size, group.dim
    g = g_default if R0 is None else val.as_array("R0", R0, (n, n))
    val.check_finite("R0", g)
    val.check_on_group("R0", group, g)
    xi = xi_default if omega0 is None else val.as_array("omega0", omega0, (r,))
    return State(g=g, xi=val.check_finite("omega0", xi))


class RigidBody(AbstractSystem):
    """Free rigid body ℓ(Ω) = ½Ωᵀ𝕀Ω on ``group`` (default SO(3)).

    ``inertia``: the r×r inertia operator in the group's coordinates or its diagonal (default
    (0.5, 0.6, 1.0) on SO(3)); or ``mass_matrix`` J (n×n symmetric or its diagonal; 𝕀Ω = JΩ + ΩJ;
    default on SO(n): J = linspace(0.55, 0.05, n)).
    """

    inertia: jnp.ndarray
    lie_group: AbstractMatrixGroup

    def __init__(self, inertia=None, *, group=None, mass_matrix=None):
        self.lie_group = _group(group)
        if isinstance(self.lie_group, SO3) or inertia is not None or mass_matrix is not None:
            self.inertia = _inertia(self.lie_group, inertia, mass_matrix, (0.5, 0.6, 1.0))
        else:
            n = self.lie_group.matrix_size
            self.inertia = _inertia(self.lie_group, None, np.linspace(0.55, 0.05, n), None)

    @property
    def group(self):
        return self.lie_group

    def lagrangian(self, xi, n, nu, a):
        return 0.5 * xi @ self.inertia @ xi

    def initial_state(self, *, R0=None, omega0=None) -> State:
        """Defaults: R0 = I, omega0 = (1.0, 0.5, −0.3) on SO(3) (embedded in the last three axes
        on SO(n))."""
        return _initial_state(self.lie_group, R0, omega0, None, (1.0, 0.5, -0.3))


class HeavyTop(AbstractSystem):
    """Heavy top on ``group`` (default SO(3)): ``inertia`` about the fixed point (r×r or its
    diagonal; default (1, 1, 0.4) on SO(3)) or ``mass_matrix`` J (default on SO(n): the Lagrange
    top J = (0.2, …, 0.2, 0.8), equal to the SO(3) default for n = 3), ``mass``, ``gravity`` and
    the centre of mass ``center_of_mass`` χ ∈ R^n (body frame; default 0.5 e_n)."""

    inertia: jnp.ndarray
    mass: jnp.ndarray
    gravity: jnp.ndarray
    center_of_mass: jnp.ndarray
    lie_group: AbstractMatrixGroup

    def __init__(
        self, inertia=None, mass=1.0, gravity=9.81, center_of_mass=None, *, group=None, mass_matrix=None
    ):
        self.lie_group = G = _group(group)
        n = G.matrix_size
        if isinstance(G, SO3) or inertia is not None or mass_matrix is not None:
            self.inertia = _inertia(G, inertia, mass_matrix, (1.0, 1.0, 0.4))
        else:
            self.inertia = _inertia(G, None, np.r_[np.full(n - 1, 0.2), 0.8], None)
        self.mass = val.check_positive_scalar("mass", jnp.asarray(mass, float))
        self.gravity = val.check_positive_scalar("gravity", jnp.asarray(gravity, float))
        chi = np.r_[np.zeros(n - 1), 0.5] if center_of_mass is None else jnp.asarray(center_of_mass, float)
        self.center_of_mass = val.check_finite("center_of_mass", val.as_array("center_of_mass", chi, (n,)))

    @property
    def group(self):
        return self.lie_group

    @property
    def advected_action(self):
        return LinearAction(self.lie_group)

    @property
    def advected_reference(self):
        return np.eye(self.lie_group.matrix_size)[-1]

    def lagrangian(self, xi, n, nu, a):
        return 0.5 * xi @ self.inertia @ xi - self.mass * self.gravity * (self.center_of_mass @ a)

    def initial_state(self, *, R0=None, omega0=None) -> State:
        """Default: tilted by 0.3 rad about e₁, spinning fast about its symmetry axis,
        omega0 = (0.3, −0.2, 6.0) (on SO(n): the SO(3) default in the last three axes)."""
        c, s = np.cos(0.3), np.sin(0.3)
        tilt = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        return _initial_state(self.lie_group, R0, omega0, tilt, (0.3, -0.2, 6.0))
