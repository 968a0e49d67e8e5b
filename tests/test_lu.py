"""Newton's LU factors (``vi_jax.solvers.lu_factor`` / ``lu_solve``): unrolled elimination
without pivoting, factored once per Jacobian and reused for every solve of a step.

The matrices are column diagonally dominant, as the Newton matrices of a step are
h-perturbations of a positive definite Hessian: elimination without pivoting then has a growth
factor ≤ 2, and the backward error bound of LU, |ΔA| ≤ γ₃ₙ|L||U| (Higham, Thm 9.4), gives
‖A x − b‖∞ ≤ 3n·ε·(2·growth)·‖A‖∞‖x‖∞, the bound asserted below.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vi_jax.solvers import dense_solve, lu_factor, lu_solve


def _dominant(rng, n, dtype):
    A = rng.normal(size=(n, n))
    A += np.diag(np.abs(A).sum(axis=0) + 1.0)  # column diagonally dominant
    return A.astype(dtype)


def _bound(A, x, dtype):
    n = A.shape[0]
    return 3 * n * np.finfo(dtype).eps * 4 * np.max(np.abs(A).sum(axis=1)) * np.max(np.abs(x))


@pytest.mark.parametrize("n", [1, 2, 3, 6, 9, 12])
def test_lu_solve_has_the_backward_error_of_lu(n):
    rng = np.random.default_rng(n)
    A, b = _dominant(rng, n, np.float64), rng.normal(size=n)
    x = np.asarray(lu_solve(lu_factor(jnp.asarray(A)), jnp.asarray(b)))
    assert np.max(np.abs(A @ x - b)) <= _bound(A, x, np.float64)
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-12, atol=1e-14)


def test_factors_reconstruct_the_matrix_and_solve_many_right_hand_sides():
    rng = np.random.default_rng(0)
    A = _dominant(rng, 6, np.float64)
    factors = lu_factor(jnp.asarray(A))
    L = np.asarray(factors.lower) + np.eye(6)
    U = np.triu(np.asarray(factors.upper))  # below the diagonal: elimination's round-off, never read
    assert np.all(np.triu(np.asarray(factors.lower)) == 0)
    np.testing.assert_allclose(L @ U, A, rtol=0, atol=8 * 6 * np.finfo(float).eps * np.abs(A).max())
    np.testing.assert_allclose(np.asarray(factors.inverse_diagonal) * np.diag(U), 1.0, rtol=4 * np.finfo(float).eps)
    B = rng.normal(size=(6, 4))
    X = np.asarray(lu_solve(factors, jnp.asarray(B)))  # columns of a matrix at once
    assert np.max(np.abs(A @ X - B)) <= _bound(A, X, np.float64)
    np.testing.assert_allclose(X, np.asarray(dense_solve(jnp.asarray(A), jnp.asarray(B))), rtol=1e-12, atol=1e-14)


def test_lu_is_jittable_vmappable_and_float32():
    rng = np.random.default_rng(1)
    As = np.stack([_dominant(rng, 4, np.float32) for _ in range(5)])
    bs = rng.normal(size=(5, 4)).astype(np.float32)
    xs = np.asarray(jax.jit(jax.vmap(lambda A, b: lu_solve(lu_factor(A), b)))(As, bs))
    assert xs.dtype == np.float32
    for A, b, x in zip(As, bs, xs):
        assert np.max(np.abs(A.astype(float) @ x - b)) <= _bound(A, x, np.float32)


def test_a_zero_pivot_gives_non_finite_values_not_a_wrong_answer():
    """No pivoting: a zero leading pivot is not repaired; Newton then reports NONFINITE."""
    A = jnp.array([[0.0, 1.0], [1.0, 0.0]])
    assert not np.all(np.isfinite(np.asarray(lu_solve(lu_factor(A), jnp.array([1.0, 2.0])))))
