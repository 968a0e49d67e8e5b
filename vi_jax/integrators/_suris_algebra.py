"""e(n) = so(n) ⋉ R^n algebra and input validation for :mod:`vi_jax.models.suris`.

Conventions follow Suris (2001), Sections 2-3 (spec 004 §0): the pairing on so(n) is
<X, Y> = -tr(XY)/2, the wedge is a∧b = a bᵀ - b aᵀ, cay(X) = (I - X)⁻¹(I + X).
"""

from __future__ import annotations

import functools
import inspect
import numbers

import jax
import jax.numpy as jnp
import numpy as np


# Algebra primitives (unvalidated, broadcasting where noted); suris.py exports validated
# versions of casimirs, orthogonal_block, to_coordinates and lie_poisson_tensor.

def pairing(X, Y):
    """<X, Y> = -tr(XY)/2 = Σ_{i<j} X_ij Y_ij on so(n) (paper §2)."""
    return -0.5 * jnp.trace(X @ Y, axis1=-2, axis2=-1)


def _from_upper(K):
    """U - Uᵀ with U the strict upper triangle of K: exactly skew in floating point.

    Writing a∧b elementwise lets XLA contract a_i b_j - a_j b_i into an FMA, which is not
    antisymmetric to the last bit; a non-skew M makes cay(M) non-orthogonal and |P| then
    drifts by ~1e-12 over 10³ steps instead of ~1e-14.
    """
    U = jnp.triu(K, 1)
    return U - jnp.swapaxes(U, -1, -2)


def wedge(a, b):
    """a∧b = a bᵀ - b aᵀ ∈ so(n); broadcasts over leading axes."""
    return _from_upper(a[..., :, None] * b[..., None, :] - b[..., :, None] * a[..., None, :])


def skew_part(X):
    """(X - Xᵀ)/2, exactly skew: keeps iterates in so(n) to the last bit."""
    return _from_upper(0.5 * (X - jnp.swapaxes(X, -1, -2)))


def cayley(X):
    """cay(X) = (I - X)⁻¹(I + X); in SO(n) for skew X."""
    eye = jnp.eye(X.shape[-1], dtype=X.dtype)
    return jnp.linalg.solve(eye - X, eye + X)


def cayley_apply(X, v):
    """cay(X) v by one linear solve."""
    eye = jnp.eye(X.shape[-1], dtype=X.dtype)
    return jnp.linalg.solve(eye - X, v + X @ v)


def orthogonal_block(M, v):
    """Π_v M Π_v with Π_v = I - v vᵀ/|v|² (Π_0 = I); NaN-safe in value and gradient.

    Conserved blocks: Π_p m Π_p by map (31), Π_A M Π_A by map (42) (spec §3a, §3c)."""
    vv = v @ v
    nonzero = vv > 0
    scale = jnp.where(nonzero, 1.0 / jnp.where(nonzero, vv, 1.0), 0.0)
    proj = jnp.eye(v.shape[-1], dtype=M.dtype) - scale * jnp.outer(v, v)
    return proj @ M @ proj


def casimirs(M, P):
    """Casimirs of e(n)* (spec 004 §2): [|P|², tr N², …, tr N^{2j}], j ≤ ⌊(n-1)/2⌋.

    N = |P|² M - (MP)∧P = |P|² Π_P M Π_P. For n = 3, tr N² = -2|P|²(μ·P)².
    """
    PP = P @ P
    N = PP * M - wedge(M @ P, P)
    N2 = N @ N
    powers, Nk = [], N2
    for _ in range((M.shape[-1] - 1) // 2):
        powers.append(jnp.trace(Nk))
        Nk = Nk @ N2
    return jnp.stack([PP, *powers])


def to_coordinates(M, P):
    """(M, P) ↦ x = (M_ij for i < j, P): the coordinates of the brackets (16)-(17)."""
    iu = np.triu_indices(M.shape[-1], 1)
    return jnp.concatenate([M[..., iu[0], iu[1]], P], axis=-1)


def from_coordinates(x, n):
    """Inverse of :func:`to_coordinates` for e(n)* with n given."""
    iu = np.triu_indices(n, 1)
    d = len(iu[0])
    upper = jnp.zeros(x.shape[:-1] + (n, n), x.dtype).at[..., iu[0], iu[1]].set(x[..., :d])
    return upper - jnp.swapaxes(upper, -1, -2), x[..., d:]


def lie_poisson_tensor(M, P):
    """Π(x)_ij = {x_i, x_j} of the e(n)* bracket (16)-(17), in :func:`to_coordinates`.

    {F1, F2} = <M, [∇_M F1, ∇_M F2]> + <∇_P F1, ∇_M F2 P> - <∇_P F2, ∇_M F1 P>; the
    rest-frame bracket (25)-(26) is -Π. Flows are ẋ = -Π ∇H (paper's sign, spec §0).
    """
    n = M.shape[-1]
    iu = np.triu_indices(n, 1)
    eye = np.eye(n)
    E = jnp.asarray(np.stack([np.outer(eye[i], eye[j]) - np.outer(eye[j], eye[i])
                              for i, j in zip(*iu)]), dtype=M.dtype)
    EE = jnp.einsum("aij,bjk->abik", E, E)
    pi_mm = pairing(M, EE - jnp.swapaxes(EE, 0, 1))
    pi_mp = -jnp.einsum("aij,j->ai", E, P)
    return jnp.block([[pi_mm, pi_mp], [-pi_mp.T, jnp.zeros((n, n), M.dtype)]])


# ---------------------------------------------------------------- validation (eager) --

def _concrete(x):
    return not isinstance(x, jax.core.Tracer)


def _as_float(name, x):
    if isinstance(x, jax.core.Tracer):
        arr = x
    else:
        try:
            arr = jnp.asarray(x)
        except TypeError as err:
            raise ValueError(f"{name}: expected a real array, got {type(x).__name__}") from err
    if jnp.issubdtype(arr.dtype, jnp.complexfloating) or arr.dtype == bool:
        raise ValueError(f"{name}: expected a real array, got dtype {arr.dtype}")
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr * 1.0 if arr.weak_type else arr.astype(jnp.result_type(float))
    return arr


def _check_finite(name, arr):
    if _concrete(arr) and not np.all(np.isfinite(np.asarray(arr))):
        raise ValueError(f"{name}: expected finite values, got {np.asarray(arr)!r}")


def _tol(arr):
    return 1e3 * float(jnp.finfo(arr.dtype).eps)


def _check_shape(name, X, expected, shape):
    if X.shape != shape:
        raise ValueError(f"{name}: expected {expected}, got shape {tuple(X.shape)}")


def check_skew(name, M, n=None):
    """M: a finite skew-symmetric n×n matrix with n ≥ 3; returns it as a float array."""
    M = _as_float(name, M)
    if M.ndim != 2 or M.shape[0] != M.shape[1] or M.shape[0] < 3:
        raise ValueError(f"{name}: expected a skew-symmetric n×n matrix with n ≥ 3, "
                         f"got shape {tuple(M.shape)}")
    if n is not None:
        _check_shape(name, M, f"a skew-symmetric {n}×{n} matrix", (n, n))
    _check_finite(name, M)
    if _concrete(M):
        m = np.asarray(M)
        asym = float(np.max(np.abs(m + m.T)))
        if asym > _tol(M) * max(1.0, float(np.max(np.abs(m)))):
            raise ValueError(f"{name}: expected a skew-symmetric matrix (M = -Mᵀ), "
                             f"got max|M + Mᵀ| = {asym:.3g}")
    return M


def check_vector(name, v, n=None):
    """v: a finite real vector of length n (any n ≥ 3 if n is None); returns a float array."""
    v = _as_float(name, v)
    if n is None and (v.ndim != 1 or v.shape[0] < 3):
        raise ValueError(f"{name}: expected a vector of length n ≥ 3, got shape {tuple(v.shape)}")
    if n is not None:
        _check_shape(name, v, f"a vector of shape ({n},)", (n,))
    _check_finite(name, v)
    return v


def check_unit(name, v, n=None):
    """v: a vector of length n with |v| = 1 (the paper's normalisation |A| = 1)."""
    v = check_vector(name, v, n)
    if _concrete(v):
        norm = float(np.linalg.norm(np.asarray(v)))
        if abs(norm - 1.0) > _tol(v):
            raise ValueError(f"{name}: expected a unit vector (|{name}| = 1, the normalisation "
                             f"of Suris (2001) §5), got |{name}| = {norm!r}")
    return v


def check_orthogonal(name, g, n=None):
    """g: a finite orthogonal n×n matrix (gᵀg = I); returns it as a float array."""
    g = _as_float(name, g)
    if g.ndim != 2 or g.shape[0] != g.shape[1] or g.shape[0] < 3:
        raise ValueError(f"{name}: expected an orthogonal n×n matrix with n ≥ 3, "
                         f"got shape {tuple(g.shape)}")
    if n is not None:
        _check_shape(name, g, f"an orthogonal {n}×{n} matrix", (n, n))
    _check_finite(name, g)
    if _concrete(g):
        arr = np.asarray(g)
        err = float(np.max(np.abs(arr.T @ arr - np.eye(arr.shape[0]))))
        if err > _tol(g):
            raise ValueError(f"{name}: expected an orthogonal matrix (gᵀg = I), "
                             f"got max|gᵀg - I| = {err:.3g}")
    return g


def check_scalar(name, x, *, positive=False, nonzero=False):
    """x: a finite real scalar, optionally > 0 or ≠ 0."""
    x = _as_float(name, x)
    if x.shape != ():
        raise ValueError(f"{name}: expected a scalar, got shape {tuple(x.shape)}")
    if _concrete(x):
        val = float(x)
        if not np.isfinite(val):
            raise ValueError(f"{name}: expected a finite scalar, got {val!r}")
        if positive and not val > 0:
            raise ValueError(f"{name}: expected a positive scalar, got {val!r}")
        if nonzero and val == 0:
            raise ValueError(f"{name}: expected a nonzero scalar, got {val!r}")
    return x


def check_n_steps(n_steps):
    """n_steps: a Python/NumPy integer ≥ 1 (it fixes the static scan length)."""
    if isinstance(n_steps, bool) or not isinstance(n_steps, numbers.Integral):
        raise ValueError(f"n_steps: expected an integer ≥ 1, got {n_steps!r} "
                         f"({type(n_steps).__name__})")
    if n_steps < 1:
        raise ValueError(f"n_steps: expected an integer ≥ 1, got {n_steps!r}")
    return int(n_steps)


def check_trajectory(name, X, ndim, n=None, rows=None):
    """X: a finite array of `ndim` axes, a leading time axis of ≥ 2 rows, then n (×n)."""
    X = _as_float(name, X)
    tail = X.shape[1:]
    if X.ndim != ndim or X.shape[0] < 2 or min(tail) < 3 or len(set(tail)) != 1:
        what = "(rows ≥ 2, n, n)" if ndim == 3 else "(rows ≥ 2, n)"
        raise ValueError(f"{name}: expected a trajectory of shape {what} with n ≥ 3, "
                         f"got shape {tuple(X.shape)}")
    if n is not None and rows is not None:
        _check_shape(name, X, f"shape {(rows,) + (n,) * (ndim - 1)}",
                     (rows,) + (n,) * (ndim - 1))
    _check_finite(name, X)
    return X


# Argument names of the public functions fix how they are validated.
_SKEW = {"m", "m0", "m_next", "M", "M0"}
_VECTOR = {"a", "a0", "a_next", "p", "P", "P0", "b", "v"}
_ORTHOGONAL = {"g", "g_next", "W"}
_TRAJECTORY = {"m_traj": 3, "M_traj": 3, "a_traj": 2}
_SCALAR = {"eps": dict(positive=True), "alpha": dict(positive=True),
           "lam": dict(nonzero=True)}


def _validate(arguments):
    out, n, rows = {}, None, None
    for name, value in arguments.items():
        if name in _SKEW:
            value = check_skew(name, value, n)
        elif name in _VECTOR:
            value = check_vector(name, value, n)
        elif name == "A":
            value = check_unit(name, value, n)
        elif name in _ORTHOGONAL:
            value = check_orthogonal(name, value, n)
        elif name in _TRAJECTORY:
            value = check_trajectory(name, value, _TRAJECTORY[name], n, rows)
            rows = value.shape[0]
        elif name in _SCALAR:
            value = check_scalar(name, value, **_SCALAR[name])
        elif name == "n_steps":
            value = check_n_steps(value)
        else:                                               # pragma: no cover
            raise TypeError(f"no validation rule for argument {name!r}")
        n = value.shape[-1] if name != "n_steps" and value.ndim else n
        out[name] = value
    if "b" in out:
        _check_clebsch(out)
    return out


def _check_clebsch(args):
    """1 + ε²|P|² b_i/4 > 0 for all i keeps the denominators of map (50) positive on the
    whole orbit (|P| is conserved) and D = (I + ε²|P|²B/4)⁻¹ of Theorem 7.1 finite."""
    p_name = next(k for k in ("P0", "P", "p") if k in args)
    P, b, eps = args[p_name], args["b"], args.get("eps")
    if eps is not None and all(_concrete(x) for x in (P, b, eps)):
        worst = float(np.min(1 + 0.25 * float(eps) ** 2 * float(P @ P) * np.asarray(b)))
        if not worst > 0:
            raise ValueError(f"b: expected 1 + eps²|{p_name}|² b_i/4 > 0 for every i (positive "
                             f"denominators in map (50)), got min = {worst!r}")


def validated(kernel):
    """Public entry point of `kernel`: its arguments are validated eagerly by name (values
    only when concrete), then the jitted kernel runs (`n_steps` is static)."""
    signature = inspect.signature(kernel)
    jitted = jax.jit(kernel, static_argnames=[k for k in signature.parameters
                                              if k == "n_steps"])

    @functools.wraps(kernel)
    def public(*args, **kwargs):
        return jitted(**_validate(signature.bind(*args, **kwargs).arguments))

    return public
