"""SO(n) for any n ≥ 2 and the translation group R^n (generic primitives from the base)."""

import itertools

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._base import AbstractMatrixGroup


class SOn(AbstractMatrixGroup):
    """SO(n); algebra coordinates x_{ij} (i < j, lexicographic), x̂ = Σ x_{ij}(e_j e_iᵀ − e_i e_jᵀ).

    With this basis the coordinate dot product equals ½tr(AᵀB). For n = 3 the ordering is
    (x_{01}, x_{02}, x_{12}); use :class:`SO3` for the cross-product convention.
    """

    n: int = eqx.field(static=True)

    def __check_init__(self):
        if not (isinstance(self.n, int) and self.n >= 2):
            raise ValueError(f"SOn: n must be an integer ≥ 2, got {self.n!r}")

    @property
    def dim(self):
        return self.n * (self.n - 1) // 2

    @property
    def matrix_size(self):
        return self.n

    def _basis(self):
        """E_{ij} = e_j e_iᵀ − e_i e_jᵀ for i < j, shape (r, n, n); ½tr(E_kᵀE_l) = δ_kl."""
        basis = np.zeros((self.dim, self.n, self.n))
        for k, (i, j) in enumerate(itertools.combinations(range(self.n), 2)):
            basis[k, j, i], basis[k, i, j] = 1.0, -1.0
        return basis

    def hat(self, xi):
        return jnp.einsum("kij,k->ij", self._basis().astype(xi.dtype), xi)

    def vee(self, X):
        return 0.5 * jnp.einsum("kij,ij->k", self._basis().astype(X.dtype), X)

    def membership_error(self, g):
        """‖gᵀg − I‖_F + |det g − 1| (the determinant rules out reflections)."""
        return jnp.linalg.norm(g.T @ g - jnp.eye(self.n, dtype=g.dtype)) + jnp.abs(jnp.linalg.det(g) - 1)

    def inverse(self, g):
        return g.T

    def Ad_dual_inv(self, g, mu):
        return self.vee(g @ self.hat(mu) @ g.T)

    def log(self, g, halvings=3):
        """Principal logarithm (rotation angles < π): 2^k log(g^{1/2^k}), each square root the
        orthogonal polar factor of I + g (Newton's polar iteration X ← ½(X + X⁻ᵀ), smooth at
        the identity), then Newton on exp."""
        eye = jnp.eye(self.n, dtype=g.dtype)
        root = g
        for _ in range(halvings):
            X = 0.5 * (eye + root)
            for _ in range(8):
                X = 0.5 * (X + jnp.linalg.inv(X).T)
            root = X
        return 2**halvings * self._log_newton(root, self.cay_inv(root))


class Rn(AbstractMatrixGroup):
    """The translation group (R^n, +) as (n+1)×(n+1) homogeneous matrices; abelian."""

    n: int = eqx.field(static=True)

    def __check_init__(self):
        if not (isinstance(self.n, int) and self.n >= 1):
            raise ValueError(f"Rn: n must be an integer ≥ 1, got {self.n!r}")

    @property
    def dim(self):
        return self.n

    @property
    def matrix_size(self):
        return self.n + 1

    def hat(self, xi):
        return jnp.zeros((self.n + 1, self.n + 1), xi.dtype).at[: self.n, self.n].set(xi, unique_indices=True)

    def vee(self, X):
        return X[: self.n, self.n]

    def membership_error(self, g):
        eye = jnp.eye(self.n + 1, dtype=g.dtype)
        return jnp.linalg.norm((g - eye).at[: self.n, self.n].set(0))

    def inverse(self, g):
        return 2 * jnp.eye(self.n + 1, dtype=g.dtype) - g

    def bracket(self, xi, eta):
        return jnp.zeros_like(xi)

    def ad(self, xi):
        return jnp.zeros((self.n, self.n), xi.dtype)

    def Ad(self, g):
        return jnp.eye(self.n, dtype=g.dtype)

    def Ad_dual_inv(self, g, mu):
        return mu

    def cay(self, x):
        return jnp.eye(self.n + 1, dtype=x.dtype) + self.hat(x)

    def cay_inv(self, g):
        return self.vee(g)

    def dcay_inv(self, x):
        return jnp.eye(self.n, dtype=x.dtype)

    exp = cay
    log = cay_inv
    dexp_inv = dcay_inv

    def rotation_angle_squared_bound(self, x):
        return jnp.zeros((), x.dtype)
