"""The scene: a Lie group, a reduced Lagrangian ℓ(ξ, n, ν, a) and optional linear actions on
the advected-parameter space V* and on the additional-dynamics space Q (seed 000 §2.2–2.3).

Absent spaces are ``None`` all the way down: a scene without advected parameters or additional
dynamics receives ``None`` for (n, ν) or a, and the engine's compiled step has none of their terms.
"""

import abc
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .lie import AbstractMatrixGroup, LinearAction


class AbstractSystem(eqx.Module):
    """Subclass and implement :attr:`group` and :meth:`lagrangian`; parameters are fields.

    Optionally provide :attr:`advected_action` with :attr:`advected_reference` (a₀ in the
    space frame), and :attr:`configuration_action` (the action on Q).
    """

    @property
    @abc.abstractmethod
    def group(self) -> AbstractMatrixGroup: ...

    @abc.abstractmethod
    def lagrangian(self, xi, n, nu, a):
        """Reduced Lagrangian ℓ(ξ, n, ν, a) (seed 000 eq. 17); absent arguments are None."""

    @property
    def advected_action(self) -> LinearAction | None:
        return None

    @property
    def advected_reference(self):
        """a₀ ∈ V*, the advected parameter in the space frame (a concrete NumPy array: its
        isotropy algebra is computed at trace time)."""
        return None

    @property
    def configuration_action(self) -> LinearAction | None:
        return None

    # --- derived quantities ---------------------------------------------------------
    @property
    def has_advected(self) -> bool:
        return self.advected_action is not None

    @property
    def has_additional(self) -> bool:
        return self.configuration_action is not None

    def body_advected(self, g):
        """a = ρ_V(g)⁻¹a₀."""
        if not self.has_advected:
            return None
        return self.advected_action.act_inverse(g, jnp.asarray(self.advected_reference, g.dtype))

    def body_configuration(self, g, q):
        """n = ρ_Q(g)⁻¹q."""
        if not self.has_additional:
            return None
        return self.configuration_action.act_inverse(g, q)

    def momenta(self, xi, n, nu, a):
        """Continuous Legendre map (μ, p) = (ℓ_ξ, ℓ_ν)."""
        mu, p = jax.grad(self.lagrangian, argnums=(0, 2))(xi, n, nu, a)
        return mu, p

    def energy(self, xi, n, nu, a):
        """E = ⟨ℓ_ξ, ξ⟩ + ⟨ℓ_ν, ν⟩ − ℓ."""
        mu, p = self.momenta(xi, n, nu, a)
        e = mu @ xi - self.lagrangian(xi, n, nu, a)
        return e if nu is None else e + p @ nu

    def isotropy_basis(self, dtype=None):
        """Columns span the isotropy algebra g_{a₀} (the whole algebra without V*)."""
        if not self.has_advected:
            return jnp.eye(self.group.dim, dtype=dtype)
        return self.advected_action.isotropy_basis(self.advected_reference, dtype)


class System(AbstractSystem):
    """A scene from plain functions: ``lagrangian(xi, n, nu, a, params)``.

    ``advected=(action, a0)`` and ``additional=action`` are optional; ``params`` is any pytree
    (differentiable).
    """

    lagrangian_fn: Callable = eqx.field(static=True)
    params: Any
    lie_group: AbstractMatrixGroup = eqx.field(static=True)
    advected: tuple | None = eqx.field(default=None, static=True)
    additional: LinearAction | None = None

    def __init__(self, group, lagrangian, params=None, *, advected=None, additional=None):
        if not isinstance(group, AbstractMatrixGroup):
            raise ValueError(f"group: expected a vi_jax.lie group, got {group!r}")
        if not callable(lagrangian):
            raise ValueError(f"lagrangian: expected a callable (xi, n, nu, a, params), got {lagrangian!r}")
        self.lie_group = group
        self.lagrangian_fn = lagrangian
        self.params = params
        if advected is not None:
            action, a0 = advected
            a0 = np.asarray(a0, dtype=float)
            # Static fields must hash by value (one compiled program per scene, not per
            # instance) and hold no arrays: a₀ is kept as its shape and a tuple of floats.
            advected = (action, a0.shape, tuple(a0.ravel().tolist()))
        self.advected = advected
        self.additional = additional

    @property
    def group(self):
        return self.lie_group

    def lagrangian(self, xi, n, nu, a):
        return self.lagrangian_fn(xi, n, nu, a, self.params)

    @property
    def advected_action(self):
        return None if self.advected is None else self.advected[0]

    @property
    def advected_reference(self):
        if self.advected is None:
            return None
        _, shape, values = self.advected
        return np.asarray(values, dtype=float).reshape(shape)

    @property
    def configuration_action(self):
        return self.additional


class State(eqx.Module):
    """Continuous initial data: g, body velocity ξ, and (with additional dynamics) q and the
    space-frame velocity q̇."""

    g: jax.Array
    xi: jax.Array
    q: jax.Array | None = None
    qdot: jax.Array | None = None
