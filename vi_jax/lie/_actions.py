"""Linear left actions of a matrix group on vector spaces, and the diamond operator.

For an action ρ: G → GL(m), the infinitesimal action is ρ'(ξ) = d/dε ρ(exp εξ̂)|₀ (one
``jax.jvp`` at the identity) and the diamond is defined by ⟨b◇x, η⟩ = −⟨b, ρ'(η)x⟩
(seed 000 eqs. 14, 24, 45), computed as one VJP.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import AbstractMatrixGroup
from ._small import matvec


_INFINITESIMAL_PROGRAMS = {}


def _infinitesimal_matrix(action, a0):
    """The matrix with columns ρ'(E_i)a₀ for a concrete a₀, from one compiled program per
    action, shape and dtype, run at once even while a caller is being traced (evaluated op by
    op instead, its first run compiled ~30 small programs: 0.3 s of a first ``vj.simulate``)."""
    a0 = np.asarray(a0)
    key = (action, a0.shape, a0.dtype)
    if key not in _INFINITESIMAL_PROGRAMS:
        columns = jax.jit(lambda a: jax.jacfwd(lambda eta: action.infinitesimal(eta, a))(jnp.zeros(action.group.dim, a.dtype)))
        _INFINITESIMAL_PROGRAMS[key] = columns.lower(jax.ShapeDtypeStruct(a0.shape, a0.dtype)).compile()
    return _INFINITESIMAL_PROGRAMS[key](a0)


class LinearAction(eqx.Module):
    """g · x = ρ(g) x for a user representation ``rho(g) -> (m, m)`` (defaults to g itself)."""

    group: AbstractMatrixGroup
    rho: Callable | None = eqx.field(default=None, static=True)

    def matrix(self, g):
        return g if self.rho is None else self.rho(g)

    def act(self, g, x):
        return matvec(self.matrix(g), x)

    def act_inverse(self, g, x):
        """ρ(g)⁻¹ x = ρ(g⁻¹) x."""
        return matvec(self.matrix(self.group.inverse(g)), x)

    def act_transpose(self, g, b):
        """ρ(g)ᵀ b (the dual action used in seed 000 eq. 42)."""
        return matvec(self.matrix(g).T, b)

    def infinitesimal(self, xi, x):
        """ρ'(ξ) x."""
        if self.rho is None:
            return matvec(self.group.hat(xi), x)
        eye = self.group.identity(xi.dtype)
        return matvec(jax.jvp(self.rho, (eye,), (self.group.hat(xi),))[1], x)

    def infinitesimal_transpose(self, xi, b):
        """ρ'(ξ)ᵀ b."""
        if self.rho is None:
            return matvec(self.group.hat(xi).T, b)
        return jax.linear_transpose(lambda x: self.infinitesimal(xi, x), b)(b)[0]

    def diamond(self, b, x):
        """b ◇ x ∈ g*: ⟨b◇x, η⟩ = −⟨b, ρ'(η)x⟩."""
        zero = jnp.zeros(self.group.dim, dtype=jnp.result_type(b, x))
        (eta_bar,) = jax.linear_transpose(lambda eta: self.infinitesimal(eta, x), zero)(b)
        return -eta_bar

    def isotropy_basis(self, a0, dtype=None):
        """Orthonormal basis (columns) of the isotropy algebra {ζ : ρ'(ζ)a₀ = 0} of a₀,
        the null space of the matrix with columns ρ'(E_i)a₀ (seed 000 spec §1). Its dimension
        is decided at trace time, so a₀ must be concrete (not traced)."""
        if isinstance(a0, jax.core.Tracer):
            raise ValueError("advected_reference: expected a concrete a₀ (not traced) for the isotropy algebra")
        a0 = np.asarray(a0)
        C = np.asarray(_infinitesimal_matrix(self, a0.astype(jax.dtypes.canonicalize_dtype(a0.dtype if dtype is None else dtype))))
        _, s, vt = np.linalg.svd(C, full_matrices=True)
        tol = max(C.shape) * np.finfo(C.dtype).eps * (s[0] if s.size else 0.0)
        rank = int(np.sum(s > tol))
        return jnp.asarray(vt[rank:].T, dtype=C.dtype)
