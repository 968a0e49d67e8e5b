"""A region of a program that XLA:CPU compiles into one kernel: a loop of small steps without a
dispatch per fused operation.

By default XLA:CPU runs a ``while`` body one thunk per fused operation, and for a step of a few
hundred flops the dispatches cost more than the arithmetic. XLA:CPU compiles a ``call`` marked
with the frontend attribute ``xla_cpu_small_call`` into a single kernel; its loop option
(``vj.enable_fast_cpu_loops()``) marks every small loop so, for the whole process. :func:`one_kernel`
marks one region of one program, whatever the process's flags: a primitive whose CPU lowering is
such a call. XLA:CPU's one-kernel emitter knows elementwise operations, reductions, slicing and
control flow, not matrix products, sorts or custom calls (LAPACK, callbacks): a region holding
anything outside :data:`KERNEL_OPS` lowers to a plain call. Elsewhere than on the CPU, and
under differentiation (the JVP of the region is the JVP of its body), the region is its body.
"""

import functools
import inspect

import jax

try:  # JAX internals: without them (a JAX that moved or changed them) a region is its body
    from jax._src import core, dispatch
    from jax._src.interpreters import ad, batching, mlir
    from jax._src.interpreters import partial_eval as pe
    from jax._src.lib.mlir import ir

    if not {"dim_var_values", "const_lowering"} <= set(inspect.signature(mlir.call_lowering).parameters):
        core = None  # pragma: no cover
except ImportError:  # pragma: no cover
    core = None

# Operations XLA:CPU's one-kernel emitter compiles: StableHLO's elementwise operations,
# reductions, data movement and control flow, and CHLO's elementwise functions (expanded into
# StableHLO before XLA sees them) but its top-k.
KERNEL_OPS = frozenset(
    "stablehlo." + name
    for name in """
    abs add and atan2 bitcast_convert broadcast_in_dim cbrt ceil clamp compare concatenate constant
    convert cosine count_leading_zeros divide dynamic_slice dynamic_update_slice exponential
    exponential_minus_one floor gather get_tuple_element if case iota is_finite log log_plus_one
    logistic maximum minimum multiply negate not optimization_barrier or pad popcnt power reduce
    remainder reshape return reverse round_nearest_afz round_nearest_even rsqrt select
    shift_left shift_right_arithmetic shift_right_logical sign sine slice sqrt subtract tan tanh
    transpose tuple while xor
    """.split()
) | {"func.call", "func.return"}
CHLO_NOT_ELEMENTWISE = frozenset({"chlo.top_k", "chlo.ragged_dot"})
# The jaxpr primitives that lower to KERNEL_OPS alone (and those holding jaxprs, checked in
# turn): the trace-time twin of the lowering's check, for a caller that picks a loop plan by it.
KERNEL_PRIMITIVES = frozenset(
    """
    abs acos acosh add add_any and argmax argmin asin asinh atan atan2 atanh bitcast_convert_type
    broadcast_in_dim cbrt ceil checkpoint clamp closed_call clz concatenate cond
    convert_element_type copy copy_p cos cosh custom_jvp_call custom_vjp_call custom_vjp_call_jaxpr
    div dynamic_slice dynamic_update_slice eq erf erf_inv erfc exp exp2 expand_dims expm1 floor
    gather ge gt imag integer_pow iota is_finite jit le log log1p logistic lt max min mul ne neg
    nextafter not optimization_barrier or pad pjit population_count pow real reduce_and reduce_max
    reduce_min reduce_or reduce_prod reduce_sum reduce_xor rem remat reshape rev round rsqrt scan
    select_n shift_left shift_right_arithmetic shift_right_logical sign sin sinh slice split sqrt
    square squeeze stack stop_gradient sub tan tanh transpose unstack while xor
    """.split()
)
SMALL_CALL = {"xla_cpu_small_call": "true", "inlineable": "false"}


def _kernel_ops_only(module, name, seen):
    """Whether function ``name`` of ``module`` (and every function it calls) holds only
    :data:`KERNEL_OPS`."""
    if name in seen:
        return True
    seen.add(name)
    callees, foreign = [], []

    def visit(op):
        if op.name not in KERNEL_OPS and not (op.name.startswith("chlo.") and op.name not in CHLO_NOT_ELEMENTWISE):
            foreign.append(op.name)
            return ir.WalkResult.INTERRUPT
        if op.name == "func.call":
            callees.append(ir.FlatSymbolRefAttr(op.attributes["callee"]).value)
        return ir.WalkResult.ADVANCE

    for op in ir.SymbolTable(module.operation)[name].regions[0].blocks[0].operations:
        op.operation.walk(visit)
        if foreign:
            return False
    return all(_kernel_ops_only(module, callee, seen) for callee in callees)


def kernel_equations(jaxpr):
    """The equations of ``jaxpr`` (a ``Jaxpr``) and of the jaxprs it holds, or None where one
    uses a primitive outside :data:`KERNEL_PRIMITIVES` (or JAX's internals are not there)."""
    if core is None:
        return None
    count = 0
    for eqn in jaxpr.eqns:
        inner = [kernel_equations(sub) for sub in core.jaxprs_in_params(eqn.params)]
        if eqn.primitive.name not in KERNEL_PRIMITIVES or None in inner:
            return None
        count += 1 + sum(inner)
    return count


if core is not None:
    one_kernel_p = core.Primitive("vi_jax_one_kernel")
    one_kernel_p.multiple_results = True
    one_kernel_p.def_abstract_eval(lambda *avals, jaxpr: jaxpr.out_avals)
    dispatch.simple_impl(one_kernel_p)

    def _body(jaxpr):
        return core.jaxpr_as_fun(jaxpr)

    def _jvp(primals, tangents, *, jaxpr):
        tangents = tuple(ad.instantiate_zeros(t) for t in tangents)
        return jax.jvp(_body(jaxpr), tuple(primals), tangents)

    def _batched(args, dims, *, jaxpr):
        in_axes = tuple(d if isinstance(d, int) else None for d in dims)
        out = one_kernel(jax.vmap(_body(jaxpr), in_axes=in_axes))(*args)
        return out, [0] * len(out)

    def _cpu_lowering(ctx, *args, jaxpr):
        out, _ = mlir.call_lowering(
            "one_kernel", jaxpr, None, ctx.module_context, ctx.avals_in, ctx.avals_out, ctx.tokens_in, *args,
            dim_var_values=ctx.dim_var_values, const_lowering=ctx.const_lowering,
        )
        call = out[0].owner
        if _kernel_ops_only(ctx.module_context.module, ir.FlatSymbolRefAttr(call.attributes["callee"]).value, set()):
            call.attributes["mhlo.frontend_attributes"] = ir.DictAttr.get({k: ir.StringAttr.get(v) for k, v in SMALL_CALL.items()})
        return out

    ad.primitive_jvps[one_kernel_p] = _jvp
    batching.primitive_batchers[one_kernel_p] = _batched
    mlir.register_lowering(one_kernel_p, mlir.lower_fun(lambda *args, jaxpr: _body(jaxpr)(*args), multiple_results=True))
    mlir.register_lowering(one_kernel_p, _cpu_lowering, platform="cpu")


def one_kernel(fn, fallback=None, max_equations=None):
    """``fn`` (arrays in, a pytree of arrays out) as a region XLA:CPU compiles into one kernel
    where it can (module docstring); the same values, JVP and batching as ``fn``. A body with
    side effects (callbacks) runs as it is. With ``fallback`` (same signature and outputs), a
    body whose jaxpr holds a primitive outside :data:`KERNEL_PRIMITIVES`, or more than
    ``max_equations`` equations (LLVM compiles a kernel in one piece), is not a region:
    ``fallback`` runs instead (e.g. ``fn`` planned for a thread-per-fusion program)."""
    if core is None:
        return fn if fallback is None else fallback

    @functools.wraps(fn)
    def region(*args):
        flat, tree = jax.tree.flatten(args)
        closed, out_shape = jax.make_jaxpr(lambda *xs: fn(*jax.tree.unflatten(tree, xs)), return_shape=True)(*flat)
        if fallback is not None:
            count = kernel_equations(closed.jaxpr)
            if count is None or (max_equations is not None and count > max_equations):
                return fallback(*args)
        if closed.effects:
            return fn(*args)
        jaxpr = pe.close_jaxpr(pe.convert_constvars_jaxpr(closed.jaxpr))  # closed-over tracers become inputs
        out = one_kernel_p.bind(*closed.consts, *flat, jaxpr=jaxpr)
        return jax.tree.unflatten(jax.tree.structure(out_shape), out)

    return region
