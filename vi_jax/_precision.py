"""Full floating-point precision for every matrix product the engines trace.

JAX lets a backend run float32 ``dot``s at reduced precision by default (TF32 on recent NVIDIA
GPUs: ~1e-3 relative instead of ~1e-7), a silent loss of three digits in exactly the float32
ensembles a GPU is used for. Every engine entry point traces under :func:`full_precision`, so its
``dot_general``s carry ``precision = HIGHEST`` (checked in tests/test_precision.py on any
backend). Element-wise small products (``vi_jax/lie/_small.py``) are exact in any case.
"""

import jax

PRECISION = "highest"


def full_precision():
    """Context manager: products traced inside it request full precision."""
    return jax.default_matmul_precision(PRECISION)
