"""Products of small matrices and vectors written as fusible elementwise code.

XLA:CPU emits every ``dot`` as a kernel of its own, and inside ``lax.scan`` each one is a
separate dispatch: for the 3×3 and 6×6 products of a step this costs more than the arithmetic.
As broadcast-multiply-sum they fuse with their neighbours. Measured by
``python benchmarks/small_products.py`` (Newton Jacobian of the trapezoid rule on the vehicle,
and whole order-2 steps).
"""

import jax.numpy as jnp


def matmul(a, b):
    """a @ b for small matrices (batch dimensions broadcast)."""
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def matvec(a, x):
    """a @ x for a small matrix and a vector."""
    return jnp.sum(a * x[..., None, :], axis=-1)


def dot(x, y):
    """x · y for small vectors."""
    return jnp.sum(x * y, axis=-1)
