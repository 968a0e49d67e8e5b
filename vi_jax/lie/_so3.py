"""SO(3) with closed-form Cayley and exponential maps (seed 000 §4, eqs. 81, 91–93)."""

import jax.numpy as jnp
import numpy as np

from . import _series
from ._base import AbstractMatrixGroup
from ._small import dot, matmul, matvec


def skew3(x):
    """x̂ with x̂y = x × y."""
    z = jnp.zeros_like(x[..., 0])
    return jnp.stack(
        [
            jnp.stack([z, -x[..., 2], x[..., 1]], -1),
            jnp.stack([x[..., 2], z, -x[..., 0]], -1),
            jnp.stack([-x[..., 1], x[..., 0], z], -1),
        ],
        -2,
    )


def unskew3(X):
    return 0.5 * jnp.stack(
        [X[..., 2, 1] - X[..., 1, 2], X[..., 0, 2] - X[..., 2, 0], X[..., 1, 0] - X[..., 0, 1]], -1
    )


def so3_exp(x):
    """Rodrigues' formula (seed 000 eq. 91), Taylor-safe at x = 0."""
    t2 = dot(x, x)
    X = skew3(x)
    eye = jnp.eye(3, dtype=x.dtype)
    return eye + _series.sinc(t2) * X + _series.one_minus_cos_over_t2(t2) * matmul(X, X)


def so3_dexp(x):
    """Right-trivialised dexp_x = I + (1−cosθ)/θ² x̂ + (θ−sinθ)/θ³ x̂² (= the left Jacobian)."""
    t2 = dot(x, x)
    X = skew3(x)
    eye = jnp.eye(3, dtype=x.dtype)
    return eye + _series.one_minus_cos_over_t2(t2) * X + _series.t_minus_sin_over_t3(t2) * matmul(X, X)


def so3_dexp_inv(x):
    """dexp⁻¹_x = I − x̂/2 + α(θ)x̂², seed 000 eqs. (92)–(93)."""
    X = skew3(x)
    eye = jnp.eye(3, dtype=x.dtype)
    return eye - 0.5 * X + _series.dexp_inv_alpha(dot(x, x)) * matmul(X, X)


def so3_cay(x):
    """cay(x) = I + 4/(4+|x|²)(x̂ + x̂²/2)."""
    X = skew3(x)
    return jnp.eye(3, dtype=x.dtype) + (4 / (4 + dot(x, x))) * (X + 0.5 * matmul(X, X))


def so3_dcay_inv(x):
    """dcay⁻¹_x = I − x̂/2 + xxᵀ/4."""
    return jnp.eye(3, dtype=x.dtype) - 0.5 * skew3(x) + 0.25 * jnp.outer(x, x)


def so3_dcay_inv_dual(x, mu):
    """(dcay⁻¹_x)ᵀμ = μ + x×μ/2 + (x·μ)x/4 (seed 000 eq. 88), without forming the matrix."""
    return mu + 0.5 * jnp.cross(x, mu) + 0.25 * dot(x, mu) * x


def so3_dexp_inv_dual(x, mu):
    """(dexp⁻¹_x)ᵀμ = μ + x×μ/2 + α(θ) x×(x×μ) (seed 000 eq. 97), without forming the matrix."""
    return mu + 0.5 * jnp.cross(x, mu) + _series.dexp_inv_alpha(dot(x, x)) * jnp.cross(x, jnp.cross(x, mu))


def so3_cay_inv(R):
    """x = 2 vee(R − Rᵀ)/(1 + tr R) (rotation angle < π); ``unskew3`` already halves."""
    return 4 * unskew3(R) / (1 + jnp.trace(R))


def so3_log(R):
    """Rotation vector of R, angle in [0, π); Taylor-safe near the identity."""
    cos = jnp.clip(0.5 * (jnp.trace(R) - 1), -1.0, 1.0)
    w = unskew3(R)  # = sinθ · axis
    sin2 = dot(w, w)
    # θ/sinθ, written as a function of sin² near θ = 0 where arccos loses accuracy.
    small = sin2 < 1e-6
    safe_sin2 = jnp.where(small, 1.0, sin2)
    theta = jnp.arctan2(jnp.sqrt(safe_sin2), cos)
    factor = jnp.where(small, 1 + sin2 / 6 + 3 * sin2**2 / 40, theta / jnp.sqrt(safe_sin2))
    return factor * w


class SO3(AbstractMatrixGroup):
    """The rotation group SO(3); algebra coordinates x with x̂y = x × y."""

    @property
    def dim(self):
        return 3

    @property
    def matrix_size(self):
        return 3

    def hat(self, xi):
        return skew3(xi)

    def vee(self, X):
        return unskew3(X)

    def membership_error(self, g):
        """‖gᵀg − I‖_F + |det g − 1| (the determinant rules out reflections)."""
        return jnp.linalg.norm(g.T @ g - np.eye(3, dtype=g.dtype)) + jnp.abs(jnp.linalg.det(g) - 1)

    def inverse(self, g):
        return g.T

    def bracket(self, xi, eta):
        return jnp.cross(xi, eta)

    def ad(self, xi):
        return skew3(xi)

    def ad_dual(self, xi, mu):
        return jnp.cross(mu, xi)

    def Ad(self, g):
        return g

    def Ad_dual_inv(self, g, mu):
        return matvec(g, mu)

    def cay(self, x):
        return so3_cay(x)

    def cay_inv(self, g):
        return so3_cay_inv(g)

    def dcay_inv(self, x):
        return so3_dcay_inv(x)

    def dcay_inv_dual(self, x, mu):
        return so3_dcay_inv_dual(x, mu)

    def dexp_inv_dual(self, x, mu):
        return so3_dexp_inv_dual(x, mu)

    def exp(self, x):
        return so3_exp(x)

    def log(self, g):
        return so3_log(g)

    def dexp_inv(self, x):
        return so3_dexp_inv(x)
