"""OpenBLAS's threaded LU under an unlimited stack limit.

Under ``ulimit -s unlimited`` (common on clusters) glibc gives every new thread a 2 MB stack
instead of the limit. JAX's CPU ``jnp.linalg.solve`` calls scipy's OpenBLAS, whose threaded LU
(``dgetrf_parallel``, for matrices of ``THREADED_LU_ENTRIES`` entries or more) recurses with
frames of about 0.5 MB on XLA's worker thread and can overflow it: a segmentation fault (a core dump of ``python benchmarks/fit_time.py``: ``dgetrf_parallel`` five
deep in an XLA worker). ``python benchmarks/openblas_threads.py`` counts the crashes of a
777 × 777 solve (the fit's Gauss–Newton system) under each stack limit and thread count. The
fit's solves are that size (9 parameters and 12 unknowns per segment); the integrators' are at
most 12 × 12, which OpenBLAS factors on one thread.

OpenBLAS reads its thread count once, when it loads (JAX loads scipy's at its first CPU linear
algebra), from the first of ``THREAD_VARIABLES`` that is set.
"""

import os
import sys

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
# OpenBLAS's dgetrf factors an m × n matrix on one thread below m·n = 10,000 (float32: 40,000;
# OpenBLAS's interface/lapack/getrf.c): smaller systems never reach the threaded LU.
THREADED_LU_ENTRIES = 10_000


def _stack_limit_unlimited() -> bool:
    if not sys.platform.startswith("linux"):  # glibc's 2 MB default applies there
        return False
    import resource

    return resource.getrlimit(resource.RLIMIT_STACK)[0] == resource.RLIM_INFINITY


def _openblas_threads() -> int | None:
    """The thread count the environment asks OpenBLAS for (None: not set; 0: not a count)."""
    value = next((os.environ[name] for name in THREAD_VARIABLES if os.environ.get(name)), None)
    if value is None:
        return None
    try:
        return int(value)
    except ValueError:
        return 0


def threaded_lu_can_overflow(order: int | None = None) -> bool:
    """Whether an LU of a square matrix of ``order`` (None: any order) may run threaded on 2 MB
    thread stacks: on Linux, the stack limit unlimited, more than one CPU, no thread count of 1
    asked for, and ``order``² ≥ ``THREADED_LU_ENTRIES``."""
    large = order is None or order * order >= THREADED_LU_ENTRIES
    return large and _stack_limit_unlimited() and (os.cpu_count() or 1) > 1 and _openblas_threads() != 1


def one_openblas_thread_if_stacks_are_small() -> bool:
    """For a process of vi_jax's own (the command line, before any computation): ask OpenBLAS
    for one thread where :func:`threaded_lu_can_overflow` and no thread count is set (a user's
    own count stands). Returns whether it did. On the fit of ``python benchmarks/fit_time.py``
    one thread cost nothing measurable on 2 cores (first fit 21.4–23.2 s against 21.5–24.6 s)."""
    if _openblas_threads() is None and threaded_lu_can_overflow():
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        return True
    return False


OVERFLOW_WARNING = (
    "the stack limit is unlimited (`ulimit -s unlimited`), so new threads get 2 MB stacks, and "
    "OpenBLAS's threaded LU, which this fit's linear solves ({order} unknowns) reach through JAX, "
    "can overflow them (a segmentation fault). Set OPENBLAS_NUM_THREADS=1, or a finite `ulimit -s`, "
    "before starting Python (the vi-jax command line does the first itself)."
)
