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

from .._xla_flags import LOOP_OPTION

FAST_LOOPS_FLAG = f"--xla_backend_extra_options={LOOP_OPTION}=1000000000"


def enable_fast_cpu_loops() -> bool:
    """Add the option to ``XLA_FLAGS`` unless the user set ``xla_backend_extra_options``
    already. Returns whether the option is now requested; it takes effect only if no JAX
    computation ran before in this process. The ``vi-jax`` command line calls it."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_extra_options" in flags:
        return LOOP_OPTION in flags
    os.environ["XLA_FLAGS"] = f"{flags} {FAST_LOOPS_FLAG}".strip()
    return True
