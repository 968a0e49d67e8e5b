"""The geometrically exact (Simo–Reissner) beam of seed 003 §5 as a covariant system on SE(3).

g = (Λ, r), ξ = g⁻¹∂_t g = (ω, γ), η = g⁻¹∂_s g = (Ω, Γ), angular parts first, and (eq. 95, Π = 0)

    ℓ(ξ, η) = ½⟨𝕁ξ, ξ⟩ − ½⟨ℂ(η − E₆), η − E₆⟩,    E₆ = (0, 0, 0, 0, 0, 1):

the reference state is straight and unstrained along the body axis e₃ (Ω = 0, Γ = e₃).

Parameters. Given by the paper: length L = 0.8 m, square section of side a = 0.01 m. Assumed
(the paper gives none; spec §5 prototype values): E = 5 MPa, ν = 0.35, ρ = 1000 kg/m³, and the
standard diagonal choice (spec §3) 𝕁 = diag(ρI₁, ρI₂, ρJ, ρA, ρA, ρA), ℂ = diag(EI₁, EI₂, GJ,
GA, GA, EA), G = E/(2(1 + ν)), I₁ = I₂ = a⁴/12, J = I₁ + I₂ as both the polar moment and the
torsion constant (St-Venant's would be 0.844·J), no shear-correction factor.

Paper grid (§5): Δs = 0.02 m, Δt = 0.04 s, T = 2 s; read as rows j = 0..50 and columns
a = 0..40 (spec §3, reading B).
"""

import warnings

import jax
import jax.numpy as jnp

from .. import _validation as val
from ..lie import SE3
from ..multisymplectic import AbstractCovariantSystem

PAPER_DT = 0.04
PAPER_DS = 0.02
PAPER_DURATION = 2.0
PAPER_XI0 = (0.0, -0.85, 0.0, 0.0, -0.1, 0.0)  # ξ_0^j, every row (§5)
PAPER_XI1 = (0.06, -0.849, -0.04, -0.03, -0.1, 0.0)  # ξ_1^j, every row (§5)
E6 = (0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def _rot_z(angle):
    c, s = jnp.cos(angle), jnp.sin(angle)
    zero, one = jnp.zeros_like(angle), jnp.ones_like(angle)
    return jnp.stack([jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]), jnp.stack([zero, zero, one])])


def _homogeneous(R, r):
    return jnp.eye(4, dtype=R.dtype).at[:3, :3].set(R).at[:3, 3].set(r)


class GeometricallyExactBeam(AbstractCovariantSystem):
    """Simo–Reissner beam: ``length`` [m], square ``side`` [m], ``youngs_modulus`` E [Pa],
    ``poisson_ratio`` ν, ``mass_density`` ρ [kg/m³] (array fields; differentiable)."""

    length: jax.Array
    side: jax.Array
    youngs_modulus: jax.Array
    poisson_ratio: jax.Array
    mass_density: jax.Array

    def __init__(self, length=0.8, side=0.01, youngs_modulus=5e6, poisson_ratio=0.35, mass_density=1000.0):
        self.length = val.check_positive_scalar("length", jnp.asarray(length, float))
        self.side = val.check_positive_scalar("side", jnp.asarray(side, float))
        self.youngs_modulus = val.check_positive_scalar("youngs_modulus", jnp.asarray(youngs_modulus, float))
        self.poisson_ratio = val.as_array("poisson_ratio", jnp.asarray(poisson_ratio, float), ())
        if val.is_concrete(self.poisson_ratio) and not -1.0 < float(self.poisson_ratio) < 0.5:
            raise ValueError(f"poisson_ratio: expected a number in (−1, 0.5), got {float(self.poisson_ratio)!r}")
        self.mass_density = val.check_positive_scalar("mass_density", jnp.asarray(mass_density, float))

    @property
    def group(self):
        return SE3()

    # --- cross-section and material ---------------------------------------------------
    @property
    def area(self):
        return self.side**2

    @property
    def second_moment(self):
        """I₁ = I₂ = a⁴/12."""
        return self.side**4 / 12

    @property
    def shear_modulus(self):
        return self.youngs_modulus / (2 * (1 + self.poisson_ratio))

    @property
    def inertia(self):
        """diag 𝕁 = (ρI₁, ρI₂, ρJ, ρA, ρA, ρA)."""
        rho, I, A = self.mass_density, self.second_moment, self.area
        return jnp.stack([rho * I, rho * I, 2 * rho * I, rho * A, rho * A, rho * A])

    @property
    def stiffness(self):
        """diag ℂ = (EI₁, EI₂, GJ, GA, GA, EA)."""
        E, G, I, A = self.youngs_modulus, self.shear_modulus, self.second_moment, self.area
        return jnp.stack([E * I, E * I, 2 * G * I, G * A, G * A, E * A])

    # --- the density (eq. 95) -----------------------------------------------------------
    def lagrangian(self, xi, eta):
        strain = eta - jnp.asarray(E6, eta.dtype)
        return 0.5 * xi @ (self.inertia * xi) - 0.5 * strain @ (self.stiffness * strain)

    def stable_time_step(self, ds):
        """The time march's stability limit (spec §6): min(Δs/c, 2/ω_rot), c = max_k √(ℂ_k/𝕁_k)
        the fastest wave speed (√(E/ρ)) and ω_rot = √(GA/(ρI)) the shear–rotary-inertia frequency."""
        ds = val.check_positive_scalar("ds", ds)
        c = jnp.sqrt(jnp.max(self.stiffness / self.inertia))
        omega_rot = jnp.sqrt(jnp.maximum(self.stiffness[3] / self.inertia[0], self.stiffness[4] / self.inertia[1]))
        return jnp.minimum(ds / c, 2 / omega_rot)

    # --- data ---------------------------------------------------------------------------
    def initial_state(
        self,
        n_nodes: int = 10,
        *,
        twist=2.0,
        spin=(0.0, 1.0, 0.5),
        velocity=(0.1, -0.05, 0.05),
        flap=0.2,
    ):
        """Time-march data on Δs = L/n_nodes: the massive nodes a = 0..n_nodes−1 (the free end
        a = n_nodes is slaved). The beam is straight along e₃ and pre-twisted by ``twist``
        [rad/m] (Λ(s) = R_z(twist·s): torsional strain Ω₃ = twist); it moves rigidly with spatial
        angular velocity ``spin`` [rad/s] and node-0 velocity ``velocity`` [m/s], plus a bending
        velocity ``flap``·cos(πs/L) e₁ [m/s]. Returns (g0 (n, 4, 4), xi0 (n, 6)) in body frame."""
        n_nodes = val.check_int("n_nodes", n_nodes, 1)
        twist = val.check_finite("twist", val.as_array("twist", jnp.asarray(twist, float), ()))
        spin = val.check_finite("spin", val.as_array("spin", jnp.asarray(spin, float), (3,)))
        velocity = val.check_finite("velocity", val.as_array("velocity", jnp.asarray(velocity, float), (3,)))
        flap = val.check_finite("flap", val.as_array("flap", jnp.asarray(flap, float), ()))
        s = self.length / n_nodes * jnp.arange(n_nodes)
        e1, e3 = jnp.eye(3)[0], jnp.eye(3)[2]

        def node(s_a):
            R, r = _rot_z(twist * s_a), s_a * e3
            v = velocity + jnp.cross(spin, r) + flap * jnp.cos(jnp.pi * s_a / self.length) * e1
            return _homogeneous(R, r), jnp.concatenate([R.T @ spin, R.T @ v])

        return jax.vmap(node)(s)

    def paper_space_data(self, dt=PAPER_DT, ds=PAPER_DS, duration=PAPER_DURATION):
        """The space march's data of §5 on rows j = 0..N−1, N = duration/dt + 1 (reading B):
        g_0^0 = (I, 0), g_1^0 = (I, (0, 0, Δs)), g_a^{j+1} = g_a^j cay(Δt ξ_a) with the paper's
        constant ξ_0, ξ_1. Returns (g_col0, g_col1), each (N, 4, 4), and warns about the data's
        inconsistencies (spec §3, problems 1–2)."""
        dt = val.check_positive_scalar("dt", dt)
        ds = val.check_positive_scalar("ds", ds)
        duration = val.check_positive_scalar("duration", duration)
        n_rows = int(round(float(duration) / float(dt))) + 1
        G = SE3()

        def column(g0, xi):
            step = G.cay(dt * jnp.asarray(xi, g0.dtype))
            return jax.lax.scan(lambda g, _: (g @ step, g), g0, None, length=n_rows)[1]

        eye = jnp.eye(4)
        col0 = column(eye, PAPER_XI0)
        col1 = column(eye.at[2, 3].set(ds), PAPER_XI1)
        eta0 = jax.vmap(lambda a, b: G.cay_inv(G.inverse(a) @ b))(col0, col1) / ds
        shear = float(jnp.max(jnp.linalg.norm(eta0[:, 3:5], axis=1)))
        stretch = float(jnp.max(jnp.abs(eta0[:, 5] - 1)))
        warnings.warn(
            "seed 003 §5 data: columns 0 and 1 move with constant nonzero velocities at every row, "
            "although the paper states zero velocity at t = 0 and t = T; its listing also imposes "
            "Ad*μ_1^{N−1} = 0, which these data violate. The space march keeps columns 0 and 1 as "
            "data and imposes the zero-momentum conditions (70) from column 2 on, with the ghost "
            "row g^N = g^{N−1} (spec §3, problem 1).",
            stacklevel=3,
        )
        if max(shear, stretch) > 0.1:
            warnings.warn(
                f"seed 003 §5 data: the strain at s = 0 reaches {100 * shear:.0f}% shear and "
                f"{100 * stretch:.0f}% stretch by t = {float(duration):g} s (node 1 does not co-move "
                "rigidly with node 0), far outside small-strain elasticity for any stiffness; the "
                "published trajectories are not reproducible from these data and the space march is "
                "expected to stop with a failed Newton solve (spec §3, problem 2).",
                stacklevel=3,
            )
        return col0, col1
