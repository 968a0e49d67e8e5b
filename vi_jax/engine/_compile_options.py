"""How a single trajectory's programs are compiled on XLA:CPU: with its elemental emitters.

The concrete calls' programs of ``vj.simulate`` (the DEP and splitting loops, the node
diagnostics) and of the beam's ``time_march`` are chains of tiny operations; XLA:CPU's elemental
emitters (``xla_cpu_use_fusion_emitters=False``) compile them in 0.55–0.75× the backend time of
its default fusion emitters (the vehicle at order 1 1.72–1.79 → 1.10 s, order 2 3.09–3.13 →
2.30–2.35 s, the heavy top at order 2 1.63–1.65 → 1.11–1.12 s, the order-4 splitting 1.17–1.20 →
0.85–0.88 s, the beam 2.13 → 1.49 s) and they run as fast or faster (0.88–1.04× per step); with
the loop option compile and run within 0.77–1.03×. Ensembles keep the fusion emitters: there the
generated step at order 2 runs 1.23–1.40× slower with the elemental ones and compiles 1.18–1.32×
longer (``python benchmarks/emitters.py [--fast-loops]``, two runs with default XLA flags).

The option goes with each program (``jax.jit``'s ``compiler_options``), not with the process:
where the user's ``XLA_FLAGS`` name the emitters, that choice stands; on another platform, or
with an XLA that no longer has the switch (it aborts on the flag, and rejects the compile
option), the programs compile as XLA's default.
"""

import functools
import os

import equinox as eqx
import jax
import jax.extend
import numpy as np

from ._placement import target_platform

EMITTERS_FLAG = "xla_cpu_use_fusion_emitters"
ELEMENTAL_EMITTERS = {EMITTERS_FLAG: False}


@functools.cache
def accepted(option: str, value) -> bool:
    """Whether this XLA compiles a CPU program with the compile option ``option=value`` (probed
    once on a program of one addition)."""
    x = jax.device_put(np.float32(0), jax.devices("cpu")[0])
    try:
        jax.jit(lambda x: x + 1, compiler_options={option: value}).lower(x).compile()
    except jax.errors.JaxRuntimeError:
        return False
    return True


def _at_top_level() -> bool:
    """Whether no transformation is tracing the caller: compile options go with top-level calls
    only (a ``jit`` nested in another is compiled with the outer one's options). False where this
    JAX no longer tells (the option is then left out, never wrongly applied)."""
    find = getattr(jax.extend.core, "find_top_trace", None)
    return find is not None and type(find(())).__name__ == "EvalTrace"


def elemental_emitters_apply() -> bool:
    """Whether a single-trajectory program called now gets the elemental emitters: it is called
    outside any transformation, targets the CPU, ``XLA_FLAGS`` do not choose the emitters, and
    this XLA has the option."""
    return (
        _at_top_level()
        and target_platform() == "cpu"
        and EMITTERS_FLAG not in os.environ.get("XLA_FLAGS", "")
        and accepted(EMITTERS_FLAG, False)
    )


def single_trajectory_jit(fn):
    """``eqx.filter_jit(fn)``, compiled with XLA:CPU's elemental emitters where
    :func:`elemental_emitters_apply` (decided at each call: the target follows
    ``jax.default_device``)."""
    default = eqx.filter_jit(fn)
    elemental = eqx.filter_jit(fn, compiler_options=ELEMENTAL_EMITTERS)

    @functools.wraps(fn)
    def program(*args, **kwargs):
        return (elemental if elemental_emitters_apply() else default)(*args, **kwargs)

    return program
