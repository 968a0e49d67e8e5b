"""Values that a per-member function computes once and reads in several places.

The generated batched step (:mod:`vi_jax.engine._components`) runs a DEP step on component
arrays, and XLA:CPU copies the whole computation of a cheap value into every fused loop that
reads it: the momentum ℓ_ξ, read by every component of the residual, was computed three times
per residual on SO(3) and the step's failure flag fifteen times. :func:`shared` marks such a
value; while :func:`marking_shared_values` is active (the generated step's tracing) the mark is
an ``optimization_barrier`` that the component interpreter turns into a fusion boundary, so each
component is computed once. Elsewhere (``vj.simulate``, ``vmap``) the mark is not traced at all.
Forward-mode tangents pass unmarked: a Jacobian's columns are read once each.
"""

import contextlib

import jax

_MARKING = False


@contextlib.contextmanager
def marking_shared_values():
    """Trace :func:`shared` as a barrier while the context is active (trace time only)."""
    global _MARKING
    previous, _MARKING = _MARKING, True
    try:
        yield
    finally:
        _MARKING = previous


def shared(x):
    """``x``, marked as computed once and read in several places (see the module)."""
    return _barrier(x) if _MARKING else x


@jax.custom_jvp
def _barrier(x):
    return jax.lax.optimization_barrier(x)


@_barrier.defjvp
def _barrier_jvp(primals, tangents):
    return _barrier(primals[0]), tangents[0]
