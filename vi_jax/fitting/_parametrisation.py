"""Unconstrained coordinates θ of the vehicle's physical parameters: exp(θ) for positive
scalars and diagonals, Cholesky factors LLᵀ (diagonal exp(θ)) for full matrices, a scaled offset
for the centre of buoyancy (see ``vi_jax.fitting._fit``)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val

from ..models import UnderwaterVehicle


PARAMETERS = ("mass", "added_mass", "inertia", "buoyancy", "buoyancy_offset")


MATRICES = ("diagonal", "full")


OFFSET_SCALE = 0.01  # m per unit of θ for the centre-of-buoyancy offset


class Parametrisation(eqx.Module):
    """Unconstrained coordinates θ of all of :data:`PARAMETERS` (see the module docstring);
    ``template`` supplies gravity and, for diagonal matrices, the off-diagonal entries."""

    template: UnderwaterVehicle
    matrices: str = eqx.field(static=True)

    def __init__(self, template, matrices="diagonal"):
        if not isinstance(template, UnderwaterVehicle):
            raise ValueError(f"guess: expected a vj.models.UnderwaterVehicle, got {type(template).__name__}")
        self.template = template
        self.matrices = val.check_choice("matrices", matrices, MATRICES)

    def _matrix_size(self):
        return 3 if self.matrices == "diagonal" else 6

    def labels(self):
        out = []
        for name in PARAMETERS:
            if name in ("mass", "buoyancy"):
                out.append(name)
            elif name == "buoyancy_offset":
                out += [f"buoyancy_offset[{i}]" for i in range(3)]
            elif self.matrices == "diagonal":
                out += [f"{name}[{i},{i}]" for i in range(3)]
            else:
                out += [f"{name}[{i},{j}]" for i, j in zip(*np.tril_indices(3))]
        return out

    def indices(self, free):
        """Positions in θ of the named parameters."""
        free = (free,) if isinstance(free, str) else tuple(free)
        if not free or any(name not in PARAMETERS for name in free) or len(set(free)) != len(free):
            raise ValueError(f"free: expected distinct names from {PARAMETERS}, got {free!r}")
        sizes = {"mass": 1, "buoyancy": 1, "buoyancy_offset": 3}
        out, start = [], 0
        for name in PARAMETERS:
            size = sizes.get(name, self._matrix_size())
            if name in free:
                out += range(start, start + size)
            start += size
        return np.asarray(out)

    def encode(self, model):
        parts = []
        for name in PARAMETERS:
            value = jnp.asarray(getattr(model, name))
            if name in ("mass", "buoyancy"):
                parts.append(jnp.log(value)[None])
            elif name == "buoyancy_offset":
                parts.append(value / OFFSET_SCALE)
            elif self.matrices == "diagonal":
                parts.append(jnp.log(jnp.diag(value)))
            else:
                L = jnp.linalg.cholesky(value)
                parts.append(jnp.where(np.eye(3, dtype=bool), jnp.log(jnp.abs(L)), L)[np.tril_indices(3)])
        return jnp.concatenate(parts)

    def decode(self, theta):
        m, k = self.template, self._matrix_size()
        sizes = {"mass": 1, "buoyancy": 1, "buoyancy_offset": 3}
        start, values = 0, {}
        for name in PARAMETERS:
            t = theta[start : start + sizes.get(name, k)]
            start += sizes.get(name, k)
            if name in ("mass", "buoyancy"):
                values[name] = jnp.exp(t[0])
            elif name == "buoyancy_offset":
                values[name] = OFFSET_SCALE * t
            elif self.matrices == "diagonal":
                old = getattr(m, name)
                values[name] = old - jnp.diag(jnp.diag(old)) + jnp.diag(jnp.exp(t))
            else:
                L = jnp.zeros((3, 3), theta.dtype).at[np.tril_indices(3)].set(t)
                L = jnp.where(np.eye(3, dtype=bool), jnp.exp(L), L)
                values[name] = L @ L.T
        return eqx.tree_at(lambda v: [getattr(v, n) for n in PARAMETERS], m, [values[n] for n in PARAMETERS])

    def values(self, model):
        """Physical values in the order of :meth:`labels`."""
        parts = []
        for name in PARAMETERS:
            value = jnp.asarray(getattr(model, name))
            if name in ("mass", "buoyancy"):
                parts.append(value[None])
            elif name == "buoyancy_offset":
                parts.append(value)
            elif self.matrices == "diagonal":
                parts.append(jnp.diag(value))
            else:
                parts.append(value[np.tril_indices(3)])
        return jnp.concatenate(parts)


class FreeParameters(eqx.Module):
    """The vehicle as a function of its free coordinates θ_free; the others stay at ``theta``'s."""

    param: Parametrisation
    theta: jax.Array
    cols: tuple = eqx.field(static=True)

    def __init__(self, param, model, free):
        self.param, self.theta = param, param.encode(model)
        self.cols = tuple(int(i) for i in param.indices(free))

    def __call__(self, theta_free):
        return self.param.decode(self.theta.at[np.asarray(self.cols)].set(theta_free))

    def initial(self):
        return self.theta[np.asarray(self.cols)]

    def labels(self):
        return [self.param.labels()[i] for i in self.cols]
