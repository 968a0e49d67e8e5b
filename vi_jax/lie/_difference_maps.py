"""Group difference maps τ: g → G (seed 000 Def. 3) and their tangent maps.

A difference map satisfies τ(0) = e and τ(−x) = τ(x)⁻¹. Each map exposes τ, τ⁻¹, the inverse
right-trivialised tangent dτ⁻¹_x (seed 000 eq. 32) and its dual (dτ⁻¹_x)* = T(x)^{−T}.
The group supplies the closed forms (SO(3), SE(3)) or the autodiff fallback.
"""

import abc

import equinox as eqx
import jax.numpy as jnp

from ._base import AbstractMatrixGroup
from ._small import matvec


class AbstractDifferenceMap(eqx.Module):
    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def tau(self, group: AbstractMatrixGroup, x):
        """τ(x) ∈ G."""

    @abc.abstractmethod
    def tau_inv(self, group: AbstractMatrixGroup, g):
        """τ⁻¹(g) ∈ g (coordinates)."""

    @abc.abstractmethod
    def dtau_inv(self, group: AbstractMatrixGroup, x):
        """Matrix of dτ⁻¹_x, the inverse right-trivialised tangent."""

    def dtau_inv_dual(self, group: AbstractMatrixGroup, x, mu):
        """(dτ⁻¹_x)* μ = T(x)^{−T} μ."""
        return matvec(self.dtau_inv(group, x).T, mu)

    def is_regular(self, group: AbstractMatrixGroup, x):
        """Whether x is inside the domain where τ is a local diffeomorphism we trust."""
        return jnp.ones((), bool)


class Cayley(AbstractDifferenceMap):
    """τ(x) = (I − x̂/2)⁻¹(I + x̂/2); never singular on compact groups."""

    name = "cayley"

    def tau(self, group, x):
        return group.cay(x)

    def tau_inv(self, group, g):
        return group.cay_inv(g)

    def dtau_inv(self, group, x):
        return group.dcay_inv(x)

    def dtau_inv_dual(self, group, x, mu):
        return group.dcay_inv_dual(x, mu)


class Exp(AbstractDifferenceMap):
    """τ = exp. dexp⁻¹ has poles at rotation angles 2πk and log is not unique beyond π, so
    :meth:`is_regular` requires every rotation angle of x to be < π (seed 000 spec §5)."""

    name = "exp"

    def tau(self, group, x):
        return group.exp(x)

    def tau_inv(self, group, g):
        return group.log(g)

    def dtau_inv(self, group, x):
        return group.dexp_inv(x)

    def dtau_inv_dual(self, group, x, mu):
        return group.dexp_inv_dual(x, mu)

    def is_regular(self, group, x):
        return group.rotation_angle_squared_bound(x) < jnp.pi**2


_DIFFERENCE_MAPS = {"cayley": Cayley, "exp": Exp}


def difference_map(tau) -> AbstractDifferenceMap:
    """Look up a difference map by name ("cayley" or "exp"), or pass an instance through."""
    if isinstance(tau, AbstractDifferenceMap):
        return tau
    if isinstance(tau, str) and tau.lower() in _DIFFERENCE_MAPS:
        return _DIFFERENCE_MAPS[tau.lower()]()
    raise ValueError(
        f"tau: expected one of {sorted(_DIFFERENCE_MAPS)} or a difference-map instance, got {tau!r}"
    )
