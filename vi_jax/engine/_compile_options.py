"""How vi_jax's programs are compiled on XLA:CPU: per-program compile options.

Single trajectories get XLA:CPU's elemental emitters. The concrete calls' programs of
``vj.simulate`` (the DEP and splitting loops, the node
diagnostics) and of the beam's ``time_march`` are chains of tiny operations; XLA:CPU's elemental
emitters (``xla_cpu_use_fusion_emitters=False``) compile them in 0.55–0.75× the backend time of
its default fusion emitters (the vehicle at order 1 1.72–1.79 → 1.10 s, order 2 3.09–3.13 →
2.30–2.35 s, the heavy top at order 2 1.63–1.65 → 1.11–1.12 s, the order-4 splitting 1.17–1.20 →
0.85–0.88 s, the beam 2.13 → 1.49 s) and they run as fast or faster (0.88–1.04× per step); with
the loop option compile and run within 0.77–1.03×. Ensembles keep the fusion emitters: there the
generated step at order 2 runs 1.23–1.40× slower with the elemental ones and compiles 1.18–1.32×
longer (``python benchmarks/emitters.py [--fast-loops]``, two runs with default XLA flags).
The fit's residual-and-Jacobian program (single trajectories differentiated in forward mode)
gets the elemental emitters too: 0.66–0.84× the compile time, 0.99–1.11× the run time
(:func:`vi_jax.fitting._shooting.residuals_and_jacobian`).

Ensembles' generated step (``ENSEMBLE_OPTIONS``) gets copy insertion by region analysis and
512-bit vectors where the CPU has them: the step's fusion boundaries are conditionals, and
XLA:CPU's default copy insertion copies every member array through them (51 copies a step on
the rigid body, 9 so; ``python benchmarks/generated_step_hlo.py``); XLA:CPU prefers 256-bit
vectors by default. Figures: ``python benchmarks/ensemble_compile_options.py [--fast-loops]``.

An option goes with each program (``jax.jit``'s ``compiler_options``), not with the process:
where the user's ``XLA_FLAGS`` name an option, that choice stands; on another platform, under a
transformation, or with an XLA that no longer has the option (it aborts on the flag, and rejects
the compile option), the programs compile without it.
"""

import functools
import os

import equinox as eqx
import jax
import numpy as np

from .. import _validation as val
from ..solvers._newton import without_implicit_gradients
from ._placement import target_platform

EMITTERS_FLAG = "xla_cpu_use_fusion_emitters"
ELEMENTAL_EMITTERS = {EMITTERS_FLAG: False}
ENSEMBLE_OPTIONS = {"xla_cpu_copy_insertion_use_region_analysis": True, "xla_cpu_prefer_vector_width": 512}


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


def options_that_apply(options: dict) -> dict:
    """The compile options of ``options`` a program called now gets: none unless it is called
    outside any transformation and targets the CPU; then those ``XLA_FLAGS`` do not name and
    this XLA has."""
    if not (val.outside_transformations() and target_platform() == "cpu"):
        return {}
    flags = os.environ.get("XLA_FLAGS", "")
    return {k: v for k, v in options.items() if k not in flags and accepted(k, v)}


def elemental_emitters_apply() -> bool:
    """Whether a single-trajectory program called now gets the elemental emitters."""
    return bool(options_that_apply(ELEMENTAL_EMITTERS))


def _forward_only(fn):
    """``fn`` traced under :func:`~vi_jax.solvers._newton.without_implicit_gradients`."""

    @functools.wraps(fn)
    def traced(*args, **kwargs):
        with without_implicit_gradients():
            return fn(*args, **kwargs)

    return traced


def cpu_options_jit(fn, options: dict, *, forward_only: bool = True):
    """``eqx.filter_jit(fn)``, compiled with :func:`options_that_apply` to ``options``, decided
    at each call (the target follows ``jax.default_device``); one program per choice, each
    reused. Called outside any transformation (concrete inputs: nothing can differentiate it)
    the program is traced without Newton's implicit-function rule, a program of its own (a
    ``jit`` under a transformation traces ``fn`` with the rule); ``forward_only=False`` keeps
    the rule there too, for a program that differentiates inside itself (the fit's Jacobian).
    ``.lower`` lowers the program of the choice; ``.chosen()`` is that program."""
    programs = {}

    def chosen():
        top = val.outside_transformations()
        key = (top, tuple(sorted(options_that_apply(options).items())))
        if key not in programs:
            body = _forward_only(fn) if top and forward_only else fn
            programs[key] = eqx.filter_jit(body, compiler_options=dict(key[1])) if key[1] else eqx.filter_jit(body)
        return programs[key]

    @functools.wraps(fn)
    def program(*args, **kwargs):
        return chosen()(*args, **kwargs)

    program.lower = lambda *args, **kwargs: chosen().lower(*args, **kwargs)
    program.chosen = chosen
    return program


def single_trajectory_jit(fn, *, forward_only: bool = True):
    """:func:`cpu_options_jit` with XLA:CPU's elemental emitters."""
    return cpu_options_jit(fn, ELEMENTAL_EMITTERS, forward_only=forward_only)
