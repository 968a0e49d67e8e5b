"""XLA:CPU option for loops of small steps.

By default XLA:CPU dispatches every fused operation of a ``while`` loop body separately; for a
step of a few hundred flops the dispatches cost more than the arithmetic. The option
``xla_cpu_small_while_loop_byte_threshold`` makes XLA compile loops whose buffers stay under the
threshold into one kernel: a vehicle step is 3.9 → 0.6 µs (order 1) and 8.6 → 2.6 µs (order 2),
diffrax's solvers gain similarly (``python benchmarks/small_products.py``,
``benchmarks/results/small_products.json``). XLA reads its flags once, when the first
computation initialises the CPU backend, so this must run before any JAX computation.
"""

import os
import warnings

from .._xla_flags import LOOP_OPTION

FAST_LOOPS_FLAG = f"--xla_backend_extra_options={LOOP_OPTION}=1000000000"


def backend_started() -> bool:
    """Whether a JAX computation has initialised the backends (XLA has read its flags). False
    where this JAX no longer tells (a JAX internal, as the engine's other uses of them): the
    option is then requested as before this check existed, instead of the command line failing."""
    try:
        from jax._src.xla_bridge import backends_are_initialized
    except ImportError:  # pragma: no cover
        return False
    return backends_are_initialized()


def enable_fast_cpu_loops() -> bool:
    """Add the option to ``XLA_FLAGS`` unless the user set ``xla_backend_extra_options``
    already. Returns whether the option is now requested. The ``vi-jax`` command line calls it.

    Call it before any JAX computation: after one, XLA has read its flags, so this warns and
    leaves ``XLA_FLAGS`` as it is (vi_jax plans its programs by ``XLA_FLAGS``: changed then, they
    would be planned for loops that XLA does not compile as one kernel)."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_extra_options" in flags:
        return LOOP_OPTION in flags
    if backend_started():
        warnings.warn(
            "enable_fast_cpu_loops: a JAX computation has already run in this process, and XLA reads "
            "its flags once, at the first one: the loop option is not enabled. Call it first (or set "
            f"XLA_FLAGS={FAST_LOOPS_FLAG} before starting Python).",
            stacklevel=2,
        )
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {FAST_LOOPS_FLAG}".strip()
    return True
