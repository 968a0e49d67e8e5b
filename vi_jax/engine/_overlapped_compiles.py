"""Two programs that run one after the other, compiled side by side on their first call.

A concrete ``vj.simulate`` runs a loop program (the steps, writing the saved nodes) and then a
program reading its rows (the node diagnostics). Compiled as one program, the first call traces
both, then compiles both; most of that compile is LLVM on the loop's one kernel, which XLA
compiles in one piece on one core. XLA compiles without holding Python's lock, so here the loop
program compiles on a thread while the second program is traced, lowered and compiled on the
other core. Later calls of the same programs find them compiled and take JAX's usual dispatch.

Which calls are first: a set of hashes of the programs' signatures (the inputs' tree, their
array shapes and dtypes, their other leaves, the default device). A collision or a cache JAX
dropped (``jax.clear_caches``) only makes a call compile its programs one after the other.
"""

import threading

import jax
import numpy as np

_compiled: set[int] = set()


def _signature(first, second, args, kwargs):
    leaves, tree = jax.tree.flatten((args, kwargs))
    spec = lambda x: (x.shape, x.dtype, getattr(x, "weak_type", False)) if isinstance(x, (jax.Array, np.ndarray, np.generic)) else x  # noqa: E731
    try:
        return hash((id(first), id(second), tree, tuple(spec(x) for x in leaves), str(jax.config.jax_default_device)))
    except TypeError:  # an unhashable leaf: eqx.filter_jit hashes it too, and would raise
        return None


def _placeholder(shape_dtype):
    """An array of the aval of ``shape_dtype`` (zeros on the host, no program compiled)."""
    return jax.device_put(np.zeros(shape_dtype.shape, shape_dtype.dtype))


def _compile(lowered):
    try:
        lowered.compile()
    except Exception:  # noqa: BLE001 — the call that follows compiles it again and raises
        pass


def run_chained(first, args, kwargs, second, second_args):
    """``(out, second(*second_args(out)))`` with ``out = first(*args, **kwargs)``; ``first`` and
    ``second`` are :func:`~._compile_options.cpu_options_jit` programs (``.lower``). On the first
    call of a signature, ``first`` compiles on a thread while ``second`` is traced and compiled
    for the avals of ``first``'s outputs."""
    key = _signature(first, second, args, kwargs)
    if key is not None and key not in _compiled:
        lowered = first.lower(*args, **kwargs)
        compiling = threading.Thread(target=_compile, args=(lowered,), daemon=True)
        compiling.start()
        try:
            outputs = jax.tree.map(_placeholder, lowered.postprocess(lowered.lowered.out_info))
            second.lower(*second_args(outputs)).compile()
        finally:
            compiling.join()
        _compiled.add(key)
    out = first(*args, **kwargs)
    return out, second(*second_args(out))
