"""Test-run configuration: float64, and two compile-time savings that leave every computed
value's definition unchanged (the suite is compile-bound: most tests build a new program).

* XLA:CPU's older elemental emitters (``--xla_cpu_use_fusion_emitters=false``) compile a
  vehicle ``simulate`` in about 0.6× the time, at 0.93–1.12× the step cost
  (``python benchmarks/compile_time.py``).
* One persistent compilation cache per test run, shared by the xdist workers and the tests'
  subprocesses (a program that two tests or two workers build is compiled once); the run's controller creates it in the
  temporary directory and removes it at the end.
"""

import os
import shutil
import tempfile

import jax

os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_use_fusion_emitters=false".strip()
_CACHE_OWNER = "VI_JAX_TEST_XLA_CACHE" not in os.environ
if _CACHE_OWNER:  # the controller (or a run without xdist); the workers inherit the variable
    os.environ["VI_JAX_TEST_XLA_CACHE"] = tempfile.mkdtemp(prefix="vi_jax_test_xla_cache_")

# As environment variables, so that the tests' subprocesses (the command line, notebooks,
# float32 and multi-device runs) share the cache too; JAX reads them at import.
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ["VI_JAX_TEST_XLA_CACHE"]
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
os.environ["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"] = "0"
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def pytest_unconfigure(config):
    if _CACHE_OWNER and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ.pop("VI_JAX_TEST_XLA_CACHE"), ignore_errors=True)
