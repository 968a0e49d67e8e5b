"""SO(n) for any n ≥ 2 and the translation group R^n (generic primitives from the base)."""

import itertools
import math

import equinox as eqx
import jax
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
        return jnp.linalg.norm(g.T @ g - np.eye(self.n, dtype=g.dtype)) + jnp.abs(jnp.linalg.det(g) - 1)

    def inverse(self, g):
        return g.T

    def Ad_dual_inv(self, g, mu):
        return self.vee(g @ self.hat(mu) @ g.T)

    def exp(self, x):
        """exp(x̂) by scaling and squaring: exp(X) = exp(X/2^s)^(2^s), s the least integer with
        ‖X/2^s‖_F ≤ ½ (‖x̂‖_F² = 2x·x); the scaled exponential is its Taylor polynomial of
        degree 15 (remainder ≤ ½¹⁶/16! ≈ 7e-19) evaluated by Paterson–Stockmeyer in six
        products; the squarings are a fixed-length loop whose steps past s are skipped. Within
        64ε(1 + ‖x̂‖_F) of scipy's Padé ``expm`` (tests/test_lie.py); derivatives finite at
        x = 0 (s comes from x·x, without a gradient); 2–3× faster to compile with them than
        ``jax.scipy.linalg.expm``, steps 0.5–1.07× (``python benchmarks/son_exp.py``)."""
        X = self.hat(x)
        needed = jnp.ceil(0.5 * jnp.log2(jax.lax.stop_gradient(2 * jnp.sum(x * x)) / 0.25))
        s = jnp.clip(needed, 0, _MAX_SQUARINGS)
        Y = X * jnp.exp2(-s).astype(X.dtype)
        powers = [jnp.eye(self.n, dtype=X.dtype), Y, Y @ Y]
        powers.append(powers[2] @ Y)
        Y4 = powers[2] @ powers[2]
        block = lambda j: sum(_TAYLOR[4 * j + i] * powers[i] for i in range(4))  # noqa: E731
        R = block(3)
        for j in (2, 1, 0):  # Σ_k Y^k/k! = ((B₃Y⁴ + B₂)Y⁴ + B₁)Y⁴ + B₀
            R = R @ Y4 + block(j)
        square = lambda i, R: jax.lax.cond(i >= _MAX_SQUARINGS - s, lambda R: R @ R, lambda R: R, R)  # noqa: E731
        R = jax.lax.fori_loop(0, _MAX_SQUARINGS, square, R)
        return jnp.where(needed > _MAX_SQUARINGS, jnp.nan, R)  # not silently inaccurate

    def log(self, g, halvings=3):
        """Principal logarithm (rotation angles < π): 2^k log(g^{1/2^k}), each square root the
        orthogonal polar factor of I + g (Newton's polar iteration X ← ½(X + X⁻ᵀ), smooth at
        the identity); then log r = 2 artanh Z with Z = (r − I)(r + I)⁻¹ = ½ cay⁻¹(r)^, skew
        with eigenvalues i·tan(θ/2), |θ| < π/2^k: Gregory's series 2Σ Z^{2j+1}/(2j+1), whose
        terms shrink by tan²(π/16) ≈ 0.04, summed to j = 11 (remainder ≤ 1e-18 relative).
        Rolled loops: one copy of each iteration to compile."""
        eye = jnp.eye(self.n, dtype=g.dtype)
        polar = lambda _, X: 0.5 * (X + jnp.linalg.inv(X).T)  # noqa: E731
        square_root = lambda _, r: jax.lax.fori_loop(0, 8, polar, 0.5 * (eye + r))  # noqa: E731
        root = jax.lax.fori_loop(0, halvings, square_root, g)
        Z = 0.5 * self.hat(self.cay_inv(root))
        Z2 = Z @ Z
        odd = lambda j: (2 * j + 1).astype(Z.dtype)  # noqa: E731
        horner = lambda i, S: eye / odd(_GREGORY_TERMS - 1 - i) + Z2 @ S  # noqa: E731
        S = jax.lax.fori_loop(0, _GREGORY_TERMS, horner, jnp.zeros_like(eye))
        return 2**halvings * self.vee(2 * Z @ S)


_TAYLOR = [1 / math.factorial(k) for k in range(16)]
_MAX_SQUARINGS = 24  # ‖x̂‖_F up to 2^23 (beyond: NaN), far beyond any rotation a step takes
_GREGORY_TERMS = 12


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
        eye = np.eye(self.n + 1, dtype=g.dtype)
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
