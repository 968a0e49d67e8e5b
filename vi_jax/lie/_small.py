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

A user's Lagrangian writes its products as it likes (``ν @ M @ ν``): :func:`fused_products`
replays a traced jaxpr with its small ``dot_general``s as multiply-and-sum, and ``vj.simulate``'s
step goes through it (Newton's residual and Jacobian, the update): 50,000 vehicle steps, every
node saved, ran 1.06× faster than with the dots kept with default XLA flags and 1.15× with the
loop option (``python benchmarks/step_cost.py``, its row "small products as dots": the step's 20
dot kernels go, its 149 fusions stay).
"""

import contextlib

import jax
import jax.numpy as jnp
from jax.extend import core as jcore

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


SMALL_PRODUCT = 512  # elements of a dot_general's broadcast product written as multiply-and-sum


def _dot_as_sum(lhs, rhs, *, dimension_numbers, preferred_element_type=None, **_):
    """``lax.dot_general`` as broadcast-multiply-sum (output axes: batch, lhs free, rhs free)."""
    (lc, rc), (lb, rb) = dimension_numbers
    lf = [d for d in range(lhs.ndim) if d not in lc and d not in lb]
    rf = [d for d in range(rhs.ndim) if d not in rc and d not in rb]
    nb, nl, nr, nc = len(lb), len(lf), len(rf), len(lc)
    lhs = jnp.transpose(lhs, (*lb, *lf, *lc))
    rhs = jnp.transpose(rhs, (*rb, *rf, *rc))
    lhs = lhs.reshape(lhs.shape[: nb + nl] + (1,) * nr + lhs.shape[nb + nl :])
    rhs = rhs.reshape(rhs.shape[:nb] + (1,) * nl + rhs.shape[nb:])
    out = jnp.sum(lhs * rhs, axis=tuple(range(nb + nl + nr, nb + nl + nr + nc)))
    return out if preferred_element_type is None else out.astype(preferred_element_type)


def _is_small_dot(eqn):
    if eqn.primitive.name != "dot_general":
        return False
    (lc, _), _ = eqn.params["dimension_numbers"]
    lhs = eqn.invars[0].aval
    contracted = 1
    for d in lc:
        contracted *= lhs.shape[d]
    return eqn.outvars[0].aval.size * contracted <= SMALL_PRODUCT


_INLINED = {"pjit": "jaxpr", "jit": "jaxpr", "closed_call": "call_jaxpr"}


def _eval_fused(jaxpr, consts, *args):
    """``jaxpr`` evaluated with its small ``dot_general``s (and those of the calls it inlines)
    as multiply-and-sum."""
    env = {}
    read = lambda v: v.val if isinstance(v, jcore.Literal) else env[v]  # noqa: E731
    env.update(zip(jaxpr.constvars, consts))
    env.update(zip(jaxpr.invars, args))
    for eqn in jaxpr.eqns:
        ins = [read(v) for v in eqn.invars]
        name = eqn.primitive.name
        if _is_small_dot(eqn):
            outs = [_dot_as_sum(*ins, **eqn.params)]
        elif name in _INLINED and eqn.params.get(_INLINED[name]) is not None:
            closed = eqn.params[_INLINED[name]]
            outs = _eval_fused(closed.jaxpr, closed.consts, *ins)
        else:
            out = eqn.primitive.bind(*ins, **eqn.primitive.get_bind_params(eqn.params))
            outs = out if eqn.primitive.multiple_results else [out]
        env.update(zip(eqn.outvars, outs))
    return [read(v) for v in jaxpr.outvars]


_KEEP_DOTS = False


@contextlib.contextmanager
def keeping_dots(enabled: bool = True):
    """While active, :func:`fused_products` replays the dots as they are: for a step that a
    ``jax.vmap`` batches, where batched dots beat multiply-and-sum (a plain ``vmap`` of
    ``vj.simulate`` over 1024 members ran 1.04–1.8× slower with multiply-and-sum, in a throwaway
    A/B when this was written; ``python benchmarks/ensemble_vs_vmap.py`` times that ``vmap``)."""
    global _KEEP_DOTS
    previous, _KEEP_DOTS = _KEEP_DOTS, bool(enabled)
    try:
        yield
    finally:
        _KEEP_DOTS = previous


def batched_by_vmap() -> bool:
    """Whether the step traced now is one a ``jax.vmap`` batches (:func:`keeping_dots`)."""
    return _KEEP_DOTS


def fused_products(closed):
    """A function replaying the closed jaxpr ``closed`` with every small ``dot_general`` (a
    product of at most ``SMALL_PRODUCT`` elements) written as multiply-and-sum, which fuses with
    its neighbours (module docstring); under :func:`batched_products` or :func:`keeping_dots` it
    replays the dots."""
    if _DOTS or _KEEP_DOTS:
        return jcore.jaxpr_as_fun(closed)
    return lambda *args: _eval_fused(closed.jaxpr, closed.consts, *args)


def traced_with_fused_products(fn, *example):
    """``fn`` (a function of arrays and pytrees of them) traced once at the shapes of
    ``example``; the returned function of such arguments replays its jaxpr by
    :func:`fused_products`."""
    closed, out_shape = jax.make_jaxpr(fn, return_shape=True)(*example)
    out_tree, replay = jax.tree.structure(out_shape), fused_products(closed)
    return lambda *args: jax.tree.unflatten(out_tree, replay(*jax.tree.leaves(args)))


def with_fused_products(fn):
    """``fn`` traced at each call and replayed by :func:`fused_products`."""
    return lambda *args: traced_with_fused_products(fn, *args)(*args)
