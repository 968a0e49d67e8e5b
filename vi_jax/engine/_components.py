"""Run a per-member function on *component arrays*: the step generator behind ``vj.ensemble``.

A per-member function (a DEP residual, its Jacobian, the explicit parts of a step) is traced
once to a jaxpr on its small arrays, and the jaxpr is evaluated again with every array held as a
numpy object array of its *components*: each entry is an array over the members (shape
(members,), or () when shared by all members) or a known constant. Every operation then acts on
whole member arrays, elementwise, so XLA fuses a Newton iteration into one vectorised loop over
the members (the member axis is the only axis of every array), whatever the group or the
Lagrangian. The small dense algebra disappears on the way: ``dot_general``, reductions,
reshapes, slices and concatenations become sums of products of components or mere
rearrangements of the object arrays, and products with the constant zeros and ones of forward-
mode bases and structure matrices are folded away at trace time.

Values marked with :func:`vi_jax._shared_values.shared` (read in several places) pass through
the caller's ``boundary``: each of their components is then computed once, not copied by XLA
into every fused loop that reads it.

Primitives without a componentwise rule run as they are under ``jax.vmap`` on the stacked
components (correct, slower); tests/test_generated_step.py checks the rules against the plain
evaluation.
"""

import operator

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend import core as jcore

from .._shared_values import marking_shared_values

_ELEMENTWISE = frozenset(
    """abs acos acosh add add_any and asin asinh atan atan2 atanh cbrt ceil clamp convert_element_type
    copy copy_p cos cosh div eq erf erf_inv exp exp2 expm1 floor ge gt integer_pow is_finite le log log1p
    logistic lt max min mul ne neg nextafter not or pow reduce_precision rem round rsqrt select_n sign sin
    sinh sqrt square stop_gradient sub tan tanh xor""".split()
)
_CALLS = {"jit": "jaxpr", "pjit": "jaxpr", "closed_call": "call_jaxpr", "core_call": "call_jaxpr",
          "remat": "jaxpr", "checkpoint": "jaxpr", "custom_jvp_call": "call_jaxpr", "custom_vjp_call": "call_jaxpr"}


def _is_const(x):
    return isinstance(x, np.generic)


def _const(value, dtype):
    return np.asarray(value, dtype)[()]


# --- elementwise primitives with constant folding -----------------------------------------


# Folded on the host: operations numpy rounds exactly as XLA does (IEEE arithmetic on equal
# dtypes, comparisons); JAX would compile a small program for the first fold of each.
_HOST_FOLDS = {"add": np.add, "add_any": np.add, "sub": np.subtract, "mul": np.multiply, "neg": np.negative,
               "eq": np.equal, "ne": np.not_equal, "lt": np.less, "le": np.less_equal, "gt": np.greater, "ge": np.greater_equal}


def _exact_conversion(value, new_dtype):
    """A conversion that is exact or IEEE rounding in numpy as in XLA (to a floating type)."""
    return jnp.issubdtype(new_dtype, jnp.floating) and (jnp.issubdtype(value.dtype, jnp.floating) or value.dtype.itemsize <= 4)


def _fold(prim, params, values):
    if prim.name in _HOST_FOLDS and len({v.dtype for v in values}) == 1:
        return _HOST_FOLDS[prim.name](*values)
    if prim.name == "convert_element_type" and _exact_conversion(values[0], params["new_dtype"]):
        return values[0].astype(params["new_dtype"])
    with jax.ensure_compile_time_eval():
        out = prim.bind(*(jnp.asarray(v) for v in values), **params)
    return np.asarray(out)[()]


def _bind(prim, params, values):
    shape = np.broadcast_shapes(*(np.shape(v) for v in values))
    values = [jnp.broadcast_to(jnp.asarray(v), shape) for v in values]
    return prim.bind(*values, **params)


def _trivial(name, a, b):
    """The result of the binary ``name`` when a constant operand makes it trivial (x·0, x·1,
    x+0, x−0, 0−x, 0/x, x/1), else None."""
    if name == "mul":
        for c, other in ((a, b), (b, a)):
            if _is_const(c) and c == 0:
                return c
            if _is_const(c) and c == 1:
                return other
    elif name in ("add", "add_any"):
        if _is_const(a) and a == 0:
            return b
        if _is_const(b) and b == 0:
            return a
    elif name == "sub":
        if _is_const(b) and b == 0:
            return a
        if _is_const(a) and a == 0 and not _is_const(b):
            return -b
    elif name == "div":
        if _is_const(a) and a == 0:
            return a
        if _is_const(b) and b == 1:
            return a
    return None


def _simplified(name, values):
    """A trivial result of ``name`` on one constant operand, or None."""
    if len(values) == 2:
        return _trivial(name, *values)
    if name == "select_n" and _is_const(values[0]):
        return values[1 + int(values[0])]
    return None


def _elementwise(eqn, operands):
    prim, params = eqn.primitive, eqn.params
    operands = np.broadcast_arrays(*operands)
    out = np.empty(operands[0].shape, object)
    for idx in np.ndindex(out.shape):
        values = [op[idx] for op in operands]
        if all(_is_const(v) for v in values):
            out[idx] = _fold(prim, params, values)
            continue
        simple = _simplified(prim.name, values)
        out[idx] = simple if simple is not None else _bind(prim, params, values)
    return out


def fold_add(a, b):
    """a + b, folding a constant zero."""
    out = _trivial("add", a, b)
    return a + b if out is None else out


def fold_sub(a, b):
    """a − b, folding a constant zero."""
    out = _trivial("sub", a, b)
    return a - b if out is None else out


def fold_mul(a, b):
    """a·b, folding constant zeros and ones."""
    out = _trivial("mul", a, b)
    return a * b if out is None else out


def _sum(values, dtype):
    total = _const(0, dtype)
    for v in values:
        total = fold_add(total, v)
    return total


# --- structural primitives: rearrangements of the object arrays ------------------------------


def _dot_general(eqn, lhs, rhs):
    (lc, rc), (lb, rb) = eqn.params["dimension_numbers"]
    dtype = eqn.outvars[0].aval.dtype
    lf = [d for d in range(lhs.ndim) if d not in lc and d not in lb]
    rf = [d for d in range(rhs.ndim) if d not in rc and d not in rb]
    batch = [lhs.shape[d] for d in lb]
    L = np.transpose(lhs, list(lb) + lf + list(lc)).reshape(int(np.prod(batch)), -1, int(np.prod([lhs.shape[d] for d in lc])))
    R = np.transpose(rhs, list(rb) + rf + list(rc)).reshape(L.shape[0], -1, L.shape[2])
    out = np.empty((L.shape[0], L.shape[1], R.shape[1]), object)
    for b, i, j in np.ndindex(out.shape):
        out[b, i, j] = _sum([fold_mul(L[b, i, k], R[b, j, k]) for k in range(L.shape[2])], dtype)
    shape = batch + [lhs.shape[d] for d in lf] + [rhs.shape[d] for d in rf]
    return out.reshape(shape)


def _reduce(eqn, x, combine):
    axes = tuple(eqn.params["axes"])
    moved = np.moveaxis(x, axes, range(-len(axes), 0)) if axes else x
    flat = moved.reshape(moved.shape[: moved.ndim - len(axes)] + (-1,))
    out = np.empty(flat.shape[:-1], object)
    for idx in np.ndindex(out.shape):
        out[idx] = combine(list(flat[idx]), eqn.outvars[0].aval.dtype)
    return out


def _combine_with(name):
    identity = {"max": -np.inf, "min": np.inf, "logical_and": True, "logical_or": False}[name]

    def combine(values, dtype):
        if not values:
            return _const(identity, dtype)
        out = values[0]
        for v in values[1:]:
            if _is_const(out) and _is_const(v):
                out = _const(getattr(np, {"max": "maximum", "min": "minimum"}.get(name, name))(out, v), dtype)
            else:
                out = {"max": jnp.maximum, "min": jnp.minimum, "logical_and": operator.and_, "logical_or": operator.or_}[name](out, v)
        return out

    return combine


def _broadcast_in_dim(eqn, x):
    shape, dims = eqn.params["shape"], eqn.params["broadcast_dimensions"]
    target = [1] * len(shape)
    for i, d in enumerate(dims):
        target[d] = x.shape[i]
    return np.broadcast_to(x.reshape(target), shape)


def _pad(eqn, x, value):
    config = eqn.params["padding_config"]
    if any(interior for _, _, interior in config) or any(lo < 0 or hi < 0 for lo, hi, _ in config):
        return None
    out = np.empty(eqn.outvars[0].aval.shape, object)
    out[...] = value[()]
    out[tuple(slice(lo, lo + n) for (lo, _, _), n in zip(config, x.shape))] = x
    return out


def _structural(eqn, ins):
    name, p = eqn.primitive.name, eqn.params
    x = ins[0] if ins else None
    if name == "broadcast_in_dim":
        return [_broadcast_in_dim(eqn, x)]
    if name == "reshape":
        return [x.reshape(p["new_sizes"])]
    if name == "squeeze":
        return [np.squeeze(x, axis=tuple(p["dimensions"]))]
    if name == "transpose":
        return [np.transpose(x, p["permutation"])]
    if name == "rev":
        return [np.flip(x, axis=tuple(p["dimensions"]))]
    if name == "slice":
        strides = p["strides"] or (1,) * x.ndim
        return [x[tuple(slice(a, b, s) for a, b, s in zip(p["start_indices"], p["limit_indices"], strides))]]
    if name == "concatenate":
        return [np.concatenate(ins, axis=p["dimension"])]
    if name == "stack":
        return [np.stack(ins, axis=p["axis"])]
    if name == "unstack":
        moved = np.moveaxis(x, p["axis"], 0)
        return [moved[i, ...] for i in range(moved.shape[0])]
    if name == "split":
        return np.split(x, np.cumsum(p["sizes"])[:-1], axis=p["axis"])
    if name == "pad":
        out = _pad(eqn, x, ins[1])
        return None if out is None else [out]
    if name == "iota":
        aval = eqn.outvars[0].aval
        shape = [1] * len(aval.shape)
        shape[p["dimension"]] = aval.shape[p["dimension"]]
        values = np.broadcast_to(np.arange(aval.shape[p["dimension"]], dtype=aval.dtype).reshape(shape), aval.shape)
        return [_constants(values)]
    if name == "dot_general":
        return [_dot_general(eqn, *ins)]
    if name == "reduce_sum":
        return [_reduce(eqn, x, _sum)]
    if name in ("reduce_max", "reduce_min"):
        return [_reduce(eqn, x, _combine_with(name[7:]))]
    if name in ("reduce_and", "reduce_or"):
        return [_reduce(eqn, x, _combine_with("logical_" + name[7:]))]
    return None


def _traced(value):
    return isinstance(value, jax.core.Tracer)


def _constants(values):
    """A jaxpr's constant as components: numpy scalars (folded at trace time), or the entries of
    a traced value the traced function closes over (e.g. a parameter being differentiated)."""
    if _traced(values):
        return components(values, False)
    values = np.asarray(values)
    out = np.empty(values.shape, object)
    for idx in np.ndindex(values.shape):
        out[idx] = values[idx][()]
    return out


# --- the interpreter -------------------------------------------------------------------------


def stacked(x, n_members):
    """Components → an array of shape (members,) + shape (also the fallback's input)."""
    flat = [jnp.broadcast_to(jnp.asarray(v), (n_members,)) for v in x.reshape(-1)]
    if not flat:
        return jnp.zeros((n_members,) + x.shape)
    return jnp.stack(flat, axis=-1).reshape((n_members,) + x.shape)


def _fallback(eqn, ins, n_members):
    """Any primitive, run as it is under ``jax.vmap`` over the stacked components."""

    def one(*args):
        out = eqn.primitive.bind(*args, **eqn.params)
        return out if eqn.primitive.multiple_results else [out]

    outs = jax.vmap(one)(*(stacked(x, n_members) for x in ins))
    return [components(o, True) for o in outs]


def _live(jaxpr):
    """The equations an output depends on (forward mode also computes primal values that a
    Jacobian does not use: not traced at all, rather than left to XLA)."""
    needed = {v for v in jaxpr.outvars if not isinstance(v, jcore.Literal)}
    live = []
    for eqn in reversed(jaxpr.eqns):
        if eqn.effects or any(v in needed for v in eqn.outvars):
            live.append(eqn)
            needed.update(v for v in eqn.invars if not isinstance(v, jcore.Literal))
    return live[::-1]


def _through_boundary(ins, boundary):
    """The operands of a shared value's barrier, their member arrays through ``boundary``."""
    if boundary is None:
        return ins
    slots = [(k, idx) for k, x in enumerate(ins) for idx in np.ndindex(x.shape) if isinstance(x[idx], jax.Array) and jnp.ndim(x[idx]) == 1]
    if not slots:
        return ins
    outs = [x.copy() for x in ins]
    for (k, idx), v in zip(slots, boundary([ins[k][idx] for k, idx in slots])):
        outs[k][idx] = v
    return outs


def _eval(jaxpr, consts, args, n_members, boundary):
    env = {}

    def read(v):
        if isinstance(v, jcore.Literal):
            return _constants(np.asarray(v.val, v.aval.dtype))
        return env[v]

    for v, x in zip(jaxpr.constvars, consts):
        env[v] = x
    for v, x in zip(jaxpr.invars, args):
        env[v] = x
    for eqn in _live(jaxpr):
        ins = [read(v) for v in eqn.invars]
        name = eqn.primitive.name
        if name in _ELEMENTWISE:
            outs = [_elementwise(eqn, ins)]
        elif name == "optimization_barrier":
            outs = _through_boundary(ins, boundary)
        elif name in _CALLS and eqn.params.get(_CALLS[name]) is not None:
            closed = eqn.params[_CALLS[name]]
            inner, inner_consts = (closed.jaxpr, [_constants(c) for c in closed.consts]) if hasattr(closed, "consts") else (closed, [])
            outs = _eval(inner, inner_consts, ins[: len(inner.invars)], n_members, boundary)
        else:
            outs = _structural(eqn, ins)
            if outs is None:
                outs = _fallback(eqn, ins, n_members)
        for v, x in zip(eqn.outvars, outs):
            if not isinstance(v, jcore.DropVar):
                env[v] = x
    return [read(v) for v in jaxpr.outvars]


def componentwise(fn, n_members):
    """``fn`` taking and returning components: every array leaf of its arguments is an object
    array of the leaf's per-member shape whose entries are member arrays (shape (members,) or
    ()) or constants. ``fn`` is traced once per argument layout (shapes and dtypes).
    ``boundary`` (a list of member arrays ↦ the same values, marked): where the values ``fn``
    marks as shared go; None: nowhere."""
    cache = {}

    def wrapped(*args, boundary=None):
        leaves, tree = jax.tree.flatten(args)
        specs = tuple(jax.ShapeDtypeStruct(np.shape(x), _leaf_dtype(x)) for x in leaves)
        key = (tree, specs)
        if key not in cache:
            with marking_shared_values():
                closed, out_shape = jax.make_jaxpr(lambda *xs: fn(*jax.tree.unflatten(tree, xs)), return_shape=True)(*specs)
            cache[key] = closed, [c if _traced(c) else _constants(c) for c in closed.consts], jax.tree.structure(out_shape)
        closed, consts, out_tree = cache[key]
        # Traced constants are split into components in the trace of this call, never cached.
        consts = [_constants(c) if _traced(c) else c for c in consts]
        return jax.tree.unflatten(out_tree, _eval(closed.jaxpr, consts, leaves, n_members, boundary))

    return wrapped


def _leaf_dtype(x):
    for v in x.reshape(-1):
        return jnp.result_type(v)
    return jnp.result_type(float)


def components(x, batched):
    """An array (leading member axis when ``batched``) as components."""
    x = jnp.asarray(x)
    shape = x.shape[1:] if batched else x.shape
    out = np.empty(shape, object)
    for idx in np.ndindex(shape):
        out[idx] = x[(slice(None),) + idx] if batched else x[idx]
    return out


def member_arrays(x, n_members, dtype=None):
    """Components → a flat tuple of arrays of shape (members,) (a loop carry)."""
    return tuple(jnp.broadcast_to(jnp.asarray(v, dtype or _leaf_dtype(x)), (n_members,)) for v in x.reshape(-1))


def from_member_arrays(flat, shape):
    out = np.empty(shape, object)
    for idx, v in zip(np.ndindex(shape), flat):
        out[idx] = v
    return out
