"""SE(3) as 4×4 homogeneous matrices; algebra coordinates (ω, v), angular part first
(seed 003 spec §2). The Cayley map is the matrix Cayley transform on 4×4 matrices."""

import jax
import jax.numpy as jnp
import numpy as np

from ._base import AbstractMatrixGroup
from ._small import dot, matmul, matvec
from ._so3 import skew3, so3_cay, so3_dcay_inv, so3_dexp, so3_dexp_inv, so3_exp, so3_log, unskew3


def _homogeneous(R, t):
    top = jnp.concatenate([R, t[:, None]], axis=1)
    bottom = jnp.concatenate([jnp.zeros((1, 3), R.dtype), jnp.ones((1, 1), R.dtype)], axis=1)
    return jnp.concatenate([top, bottom], axis=0)


def _block_lower(A, C):
    """[[A, 0], [C, A]] for 3×3 blocks."""
    z = jnp.zeros_like(A)
    return jnp.block([[A, z], [C, A]])


class SE3(AbstractMatrixGroup):
    """Rigid motions g = (R, r) with product (R₁R₂, r₁ + R₁r₂)."""

    @property
    def dim(self):
        return 6

    @property
    def matrix_size(self):
        return 4

    def hat(self, xi):
        X = jnp.concatenate([skew3(xi[:3]), xi[3:, None]], axis=1)
        return jnp.concatenate([X, jnp.zeros((1, 4), xi.dtype)], axis=0)

    def vee(self, X):
        return jnp.concatenate([unskew3(X[:3, :3]), X[:3, 3]])

    def membership_error(self, g):
        R = g[:3, :3]
        bottom = g[3] - np.array([0, 0, 0, 1], g.dtype)
        orthogonality = jnp.sqrt(jnp.sum((R.T @ R - np.eye(3, dtype=g.dtype)) ** 2) + jnp.sum(bottom**2))
        return orthogonality + jnp.abs(jnp.linalg.det(R) - 1)

    def inverse(self, g):
        R, r = g[:3, :3], g[:3, 3]
        return _homogeneous(R.T, -matvec(R.T, r))

    def bracket(self, xi, eta):
        w1, v1, w2, v2 = xi[:3], xi[3:], eta[:3], eta[3:]
        return jnp.concatenate([jnp.cross(w1, w2), jnp.cross(w1, v2) - jnp.cross(w2, v1)])

    def ad(self, xi):
        return _block_lower(skew3(xi[:3]), skew3(xi[3:]))

    def Ad(self, g):
        R, r = g[:3, :3], g[:3, 3]
        return _block_lower(R, matmul(skew3(r), R))

    def Ad_dual_inv(self, g, mu):
        """(π, p) ↦ (Rπ + r × Rp, Rp): spatial angular momentum about the origin and linear momentum."""
        R, r = g[:3, :3], g[:3, 3]
        p = matvec(R, mu[3:])
        return jnp.concatenate([matvec(R, mu[:3]) + jnp.cross(r, p), p])

    def cay(self, x):
        w, v = x[:3], x[3:]
        t = (4 * v + 2 * jnp.cross(w, v) + w * dot(w, v)) / (4 + dot(w, w))
        return _homogeneous(so3_cay(w), t)

    def cay_inv(self, g):
        R, r = g[:3, :3], g[:3, 3]
        w = 4 * unskew3(R) / (1 + jnp.trace(R))
        return jnp.concatenate([w, r - 0.5 * jnp.cross(w, r)])

    def dcay_inv(self, x):
        """[[I − ω̂/2 + ωωᵀ/4, 0], [−½(I − ω̂/2)v̂, I − ω̂/2]] (seed 003 spec §2)."""
        w, v = x[:3], x[3:]
        eye = jnp.eye(3, dtype=x.dtype)
        A = eye - 0.5 * skew3(w)
        top = jnp.concatenate([so3_dcay_inv(w), jnp.zeros((3, 3), x.dtype)], axis=1)
        bottom = jnp.concatenate([-0.5 * matmul(A, skew3(v)), A], axis=1)
        return jnp.concatenate([top, bottom], axis=0)

    def exp(self, x):
        w, v = x[:3], x[3:]
        return _homogeneous(so3_exp(w), matvec(so3_dexp(w), v))

    def log(self, g):
        w = so3_log(g[:3, :3])
        return jnp.concatenate([w, so3_dexp_inv(w) @ g[:3, 3]])

    def dexp_inv(self, x):
        """Block inverse of dexp_x = [[A, 0], [Q, A]], A = dexp_ω(SO(3)),
        Q = ∂_ω(A(ω)v) + (A v)^A: dexp⁻¹ = [[A⁻¹, 0], [−A⁻¹QA⁻¹, A⁻¹]]."""
        w, v = x[:3], x[3:]
        A = so3_dexp(w)
        A_inv = so3_dexp_inv(w)
        Q = jax.jacfwd(lambda u: so3_dexp(u) @ v)(w) + skew3(A @ v) @ A
        return _block_lower(A_inv, -A_inv @ Q @ A_inv)

    def rotation_angle_squared_bound(self, x):
        return dot(x[:3], x[:3])
