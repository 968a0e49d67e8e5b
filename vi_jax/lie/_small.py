"""Products of small matrices and vectors written as fusible elementwise code.

XLA:CPU emits every ``dot`` as a kernel of its own, and inside ``lax.scan`` each one is a
separate dispatch: for the 3×3 and 6×6 products of a step this costs more than the arithmetic.
As broadcast-multiply-sum they fuse with their neighbours. Measured by
``python benchmarks/small_products.py`` (Newton Jacobian of the trapezoid rule on the vehicle,
and whole order-2 steps).

Under a large ``vmap`` on CPU it is the other way round: batched dots beat the elementwise form
(a Cayley Jacobian over 1024 members: 0.22 µs per member-step with dots, 0.98 µs fused, same
benchmark). :func:`batched_products` switches to dots while a batched program is traced
(``vj.ensemble`` on CPU); it acts at trace time only.
"""

import contextlib

import jax.numpy as jnp

_DOTS = False


@contextlib.contextmanager
def batched_products(enabled: bool = True):
    """Trace the products below as dots (``jnp.matmul``) while the context is active."""
    global _DOTS
    previous, _DOTS = _DOTS, bool(enabled)
    try:
        yield
    finally:
        _DOTS = previous


def matmul(a, b):
    """a @ b for small matrices (batch dimensions broadcast)."""
    if _DOTS:
        return jnp.matmul(a, b)
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def matvec(a, x):
    """a @ x for a small matrix and a vector."""
    if _DOTS:
        return jnp.matmul(a, x[..., None])[..., 0]
    return jnp.sum(a * x[..., None, :], axis=-1)


def dot(x, y):
    """x · y for small vectors."""
    if _DOTS:
        return jnp.matmul(x[..., None, :], y[..., :, None])[..., 0, 0]
    return jnp.sum(x * y, axis=-1)
