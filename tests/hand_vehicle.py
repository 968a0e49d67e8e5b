"""Independent hand implementation of the paper's vectorised underwater-vehicle schemes
(seed 000 eqs. 73–74 with 88–90 for Cayley and 94–100 for exp, with the spec's errata:
corrected Jacobians (90) and (99), α evaluated at h|ω|), written directly from the paper with
closed-form Jacobians and a 3×3 Cramer solve. Used to cross-check the generic engine and as the
hand-specialised peer in ``benchmarks/step_cost.py``.

State at node k: (R_k, q_k, M_k = f_{−h}(ω_{k−1}), P_k = τ(−hω_{k−1})Mν_{k−1}), started from the
continuous Legendre map M₀ = Jω₀, P₀ = (mI + M_A)ν₀.
"""

import jax
import jax.numpy as jnp

E_Z = jnp.array([0.0, 0.0, 1.0])


def hat(x):
    return jnp.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


def inv3(A):
    """Closed-form 3×3 inverse (adjugate / determinant)."""
    c0, c1, c2 = jnp.cross(A[1], A[2]), jnp.cross(A[2], A[0]), jnp.cross(A[0], A[1])
    return jnp.stack([c0, c1, c2], axis=1) / (A[0] @ c0)


def cayley(x):
    X = hat(x)
    return jnp.eye(3) + 4.0 / (4.0 + x @ x) * (X + 0.5 * X @ X)


def f_cayley(w, J, h):
    """Eq. (88) simplified by (85): Jω + (h/2)ω×Jω + (h²/4)(ω·Jω)ω."""
    Jw = J @ w
    return Jw + 0.5 * h * jnp.cross(w, Jw) + 0.25 * h**2 * (w @ Jw) * w


def jac_cayley(w, J, h):
    """Corrected eq. (90): J + (h/2)(ω̂J − (Jω)^) + (h²/4)(2ω(Jω)ᵀ + (ω·Jω)I)."""
    Jw = J @ w
    return J + 0.5 * h * (hat(w) @ J - hat(Jw)) + 0.25 * h**2 * (2 * jnp.outer(w, Jw) + (w @ Jw) * jnp.eye(3))


def alpha(theta):
    """α(θ) = (1 − (θ/2)cot(θ/2))/θ² (eq. 93), series below θ = 0.1."""
    small = theta < 0.1
    t = jnp.where(small, 1.0, theta)
    closed = (1 - 0.5 * t / jnp.tan(0.5 * t)) / t**2
    series = 1 / 12 + theta**2 / 720 + theta**4 / 30240 + theta**6 / 1209600
    return jnp.where(small, series, closed)


def alpha_prime_over_theta(theta):
    """α'(θ)/θ, so that ∇_x α(|x|) = (α'/θ) x (eq. 100); series below θ = 0.1."""
    small = theta < 0.1
    t = jnp.where(small, 1.0, theta)
    cot = 1 / jnp.tan(0.5 * t)
    numerator = 1 - 0.5 * t * cot
    d_numerator = -0.5 * cot + 0.25 * t / jnp.sin(0.5 * t) ** 2
    closed = (d_numerator / t**2 - 2 * numerator / t**3) / t
    series = 1 / 360 + theta**2 / 7560 + theta**4 / 201600
    return jnp.where(small, series, closed)


def rodrigues(x):
    theta = jnp.sqrt(x @ x)
    X = hat(x)
    small = theta < 1e-4
    t = jnp.where(small, 1.0, theta)
    a = jnp.where(small, 1 - theta**2 / 6, jnp.sin(t) / t)
    b = jnp.where(small, 0.5 - theta**2 / 24, (1 - jnp.cos(t)) / t**2)
    return jnp.eye(3) + a * X + b * X @ X


def f_exp(w, J, h):
    """Eqs. (94)–(97) with the erratum α = α(h|ω|): Jω + (h/2)ω×Jω + h²α ω×(ω×Jω)."""
    Jw = J @ w
    theta = h * jnp.sqrt(w @ w)
    return Jw + 0.5 * h * jnp.cross(w, Jw) + h**2 * alpha(theta) * jnp.cross(w, jnp.cross(w, Jw))


def jac_exp(w, J, h):
    """Corrected eq. (99): the rank-one term is h²·v·(∇_ω α)ᵀ with v = ω×(ω×Jω), and
    ∇_ω α(h|ω|) = h·∇α(x) at x = hω."""
    Jw = J @ w
    theta = h * jnp.sqrt(w @ w)
    v = jnp.cross(w, jnp.cross(w, Jw))
    dv = (w @ Jw) * jnp.eye(3) + jnp.outer(w, Jw) + jnp.outer(w, w) @ J - 2 * jnp.outer(Jw, w) - (w @ w) * J
    grad_alpha = h * alpha_prime_over_theta(theta) * (h * w)
    return J + 0.5 * h * (hat(w) @ J - hat(Jw)) + h**2 * (alpha(theta) * dv + jnp.outer(v, grad_alpha))


SCHEMES = {"cayley": (f_cayley, jac_cayley, cayley), "exp": (f_exp, jac_exp, rodrigues)}


def make_step(params, h, tau="cayley", newton_iterations=3):
    """One step of eqs. (73)–(74): ν_k explicit, ω_k by Newton on f_h(ω_k) = rhs."""
    m, MA, J, B, g, r = params
    f, jac, group_map = SCHEMES[tau]
    mass = m * jnp.eye(3) + MA
    mass_inv = inv3(mass)
    W = m * g

    def step(carry, _):
        R, q, M, P, w = carry
        a = R.T @ E_Z
        Mnu = P + h * (W - B) * a  # eq. (74)
        nu = mass_inv @ Mnu
        rhs = M - h * B * jnp.cross(r, a) + h * jnp.cross(Mnu, nu)  # eq. (73)
        for _ in range(newton_iterations):
            w = w - inv3(jac(w, J, h)) @ (f(w, J, h) - rhs)
        lam = group_map(h * w)
        new = (R @ lam, q + h * R @ nu, f(w, J, -h), lam.T @ Mnu, w)
        return new, (new[0], new[1], new[2], new[3])

    return step


def simulate_hand(params, R0, q0, omega0, v0, h, n_steps, tau="cayley", newton_iterations=3):
    """(R, q, M, P) at nodes 1..n_steps."""
    m, MA, J, *_ = params
    nu0 = R0.T @ v0
    carry = (R0, q0, J @ omega0, (m * jnp.eye(3) + MA) @ nu0, omega0)
    _, out = jax.lax.scan(make_step(params, h, tau, newton_iterations), carry, None, length=n_steps)
    return out


def node_diagnostics_hand(params, R, q, M, P):
    """Per node (leading axis), from the saved (R, q, M, P): the continuous inverse Legendre map
    ω = J⁻¹M, ν = (mI + M_A)⁻¹P (eq. 62's ℓ is quadratic in the velocities), the energy
    E = ½νᵀ(mI + M_A)ν + ½ωᵀJω − (W − B) n·a + B r·a with n = Rᵀq and a = Rᵀe_z, the
    Kelvin–Noether quantity of the isotropy of e_z, e_z·R(M − P×n) (spec: Ad*_{g⁻¹}μ = Rμ,
    b◇x = b×x), and its scale |M| + |P||n|."""
    m, MA, J, B, g, r = params
    mass = m * jnp.eye(3) + MA
    omega, nu = M @ inv3(J).T, P @ inv3(mass).T
    n = jnp.einsum("kji,kj->ki", R, q)
    a = R[:, 2, :]
    dot = lambda x, y: jnp.sum(x * y, axis=-1)  # noqa: E731
    energy = 0.5 * dot(nu, nu @ mass.T) + 0.5 * dot(omega, omega @ J.T) - (m * g - B) * dot(n, a) + B * (a @ r)
    kelvin_noether = dot(a, M - jnp.cross(P, n))  # e_z·Rμ = (Rᵀe_z)·μ
    scale = jnp.linalg.norm(M, axis=-1) + jnp.linalg.norm(P, axis=-1) * jnp.linalg.norm(n, axis=-1)
    return omega, nu, energy, kelvin_noether, scale


def vehicle_params(model):
    return (model.mass, model.added_mass, model.inertia, model.buoyancy, model.gravity, model.buoyancy_offset)


def eq65(model, R, w, q, nu):
    """The paper's continuous equations (65), written out by hand: (Ṙ, ω̇, q̇, ν̇)."""
    m, MA, J, B, g, r = vehicle_params(model)
    mass = m * jnp.eye(3) + MA
    a = R.T @ E_Z
    Mnu = mass @ nu
    dw = jnp.linalg.solve(J, jnp.cross(J @ w, w) - B * jnp.cross(r, a) + jnp.cross(Mnu, nu))
    dnu = jnp.linalg.solve(mass, (m * g - B) * a - jnp.cross(w, Mnu))
    return R @ hat(w), dw, R @ nu, dnu
