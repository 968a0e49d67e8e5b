"""Compiled programs kept between concrete calls: a call whose inputs have the tree structure,
shapes, dtypes, weak types, placement and static values of an earlier one, under the same JAX
configuration, runs that call's compiled program instead of lowering and compiling it again.

``jax.jit`` keeps its programs itself, but a program run from worker threads
(:func:`~._member_groups.on_cores`) is compiled in the calling thread, where the caller's
configuration contexts hold (``jax.default_device``, precision, x64), and run as a compiled
object. Lowered and compiled anew each call (a hit in JAX's caches, yet 0.4-0.6 ms) and run as
a fresh compiled object, a concrete call of 1024 vehicle members took 0.7-2.4 ms longer by
medians at 1000 steps (of 24-30 ms) and 0.5-1.2 ms at 4 steps, default XLA and with the loop
option (``python benchmarks/ensemble_call_overhead.py [--fast-loops]``).

The kept programs follow JAX's own caches: the key holds JAX's trace context (the
configuration ``jit`` keys on) and the program variant a :func:`~._compile_options.cpu_options_jit`
function chooses now, and ``jax.clear_caches()`` drops them (a switch read at trace time then
takes effect, as it does for ``jit``). Inputs with a leaf that cannot be hashed, or traced, are
compiled every time.
"""

import collections
import threading

import jax
import numpy as np

try:  # JAX internals: without them no program is kept (every call compiles)
    from jax._src.config import trace_context
    from jax._src.util import register_cache
except ImportError:  # pragma: no cover
    trace_context = None

KEPT = 8  # programs kept at most, the least recently used dropped first


class _Kept:
    """The kept programs, registered with JAX's cache management (``jax.clear_caches()``)."""

    def __init__(self):
        self.programs = collections.OrderedDict()
        self.lock = threading.Lock()

    def cache_clear(self):
        with self.lock:
            self.programs.clear()

    def cache_info(self):
        return len(self.programs)

    def cache_keys(self):
        return list(self.programs)


_KEPT = _Kept()
if trace_context is not None:
    register_cache(_KEPT, "vi_jax: compiled programs of concrete calls run from worker threads")


def compiled_program(program, *args, **kwargs):
    """``program.lower(*args, **kwargs).compile()``, kept for the next call with the same
    signature (module docstring)."""
    key = _signature(program, args, kwargs)
    if key is not None:
        with _KEPT.lock:
            out = _KEPT.programs.get(key)
            if out is not None:
                _KEPT.programs.move_to_end(key)
                return out
    out = program.lower(*args, **kwargs).compile()
    if key is not None:
        with _KEPT.lock:
            _KEPT.programs[key] = out
            while len(_KEPT.programs) > KEPT:
                _KEPT.programs.popitem(last=False)
    return out


class _Traced(Exception):
    pass


def _leaf(x):
    """What ``jit`` specialises a program on: an array's type and placement, any other leaf's
    value (``eqx.filter_jit`` makes it static), with its type."""
    if isinstance(x, jax.core.Tracer):
        raise _Traced
    if isinstance(x, jax.Array):
        return "array", x.shape, x.dtype, x.weak_type, x.sharding
    if isinstance(x, (np.ndarray, np.generic)):
        return "numpy", np.shape(x), x.dtype
    return "static", type(x), x


def _signature(program, args, kwargs):
    if trace_context is None:
        return None
    leaves, treedef = jax.tree.flatten((args, kwargs))
    chosen = getattr(program, "chosen", None)
    try:
        key = (program if chosen is None else chosen(), treedef, tuple(map(_leaf, leaves)), trace_context())
        hash(key)
    except (_Traced, TypeError):
        return None
    return key
