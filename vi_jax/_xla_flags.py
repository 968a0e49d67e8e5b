"""Which XLA:CPU loop plan this process runs under (read from ``XLA_FLAGS``, which XLA reads once
when the backend starts): code whose best form differs between the plans asks here at trace time."""

import os

import jax

LOOP_OPTION = "xla_cpu_small_while_loop_byte_threshold"


def loop_option_requested() -> bool:
    """Whether ``XLA_FLAGS`` asks XLA:CPU to compile small ``while`` loops into one kernel
    (``vj.enable_fast_cpu_loops()``) and the default backend is the CPU."""
    return LOOP_OPTION in os.environ.get("XLA_FLAGS", "") and jax.default_backend() == "cpu"
