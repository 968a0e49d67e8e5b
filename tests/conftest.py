"""Test-run configuration: float64, and three compile-time savings that leave every computed
value's definition unchanged (the suite is compile-bound: most tests build a new program).

* XLA:CPU's older elemental emitters (``--xla_cpu_use_fusion_emitters=false``) spend
  0.51–0.78× the backend compile time, at 0.73–1.41× the step cost, within the run-to-run
  spread (two runs of ``python benchmarks/compile_time.py``).
* LLVM at -O0 (``--xla_backend_optimization_level=0``): the same optimised HLO, machine code
  compiled without LLVM's passes. The whole suite: backend compile 366 against 732 s of the
  workers' time, 479 against 668 s wall (``python benchmarks/suite_profile.py``: the suite at
  levels 0 and 3 one after the other, JAX's monitoring events summed per test);
  vj.simulate's programs compile in 0.4× the time and run 6× slower (``compile_time.py``'s
  child, three scenes), which the tests' short runs do not feel. Values change by round-off
  only; users and the benchmarks compile at XLA's default level.
* Each flag is added where XLA_FLAGS do not name it already (a run at XLA's default level:
  ``XLA_FLAGS=--xla_backend_optimization_level=3 python -m pytest``) and this XLA still knows it
  (probed once per run: XLA aborts on an unknown flag).
* One persistent compilation cache per test run, shared by the xdist workers and the tests'
  subprocesses (a program that two tests or two workers build is compiled once); the run's
  controller creates it in the temporary directory and removes it at the end.
"""

import os
import shutil
import subprocess
import sys
import tempfile

# Before scipy's OpenBLAS loads (JAX loads it at its first CPU linear algebra): one OpenBLAS thread.
# Under `ulimit -s unlimited` (as .ci/run once set) glibc gives threads 2 MB stacks, which
# OpenBLAS's threaded LU can overflow (vi_jax/_openblas_threads.py): two fresh-clone runs of this
# suite crashed in libscipy_openblas, and the noise-free fit of tests/test_fit.py alone
# segfaulted in 2 of 6 runs.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

_FAST_COMPILES = ("--xla_cpu_use_fusion_emitters=false", "--xla_backend_optimization_level=0")
_CACHE_OWNER = "VI_JAX_TEST_XLA_CACHE" not in os.environ
if _CACHE_OWNER:  # the controller (or a run without xdist); the workers inherit the variables
    os.environ["VI_JAX_TEST_XLA_CACHE"] = tempfile.mkdtemp(prefix="vi_jax_test_xla_cache_")
    for _flag in _FAST_COMPILES:
        if _flag.split("=")[0] in os.environ.get("XLA_FLAGS", ""):
            continue
        # XLA aborts the process on a flag it does not know (newer XLA dropped some): probe it.
        flags = f"{os.environ.get('XLA_FLAGS', '')} {_flag}".strip()
        probe = subprocess.run(
            [sys.executable, "-c", "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"],
            env=dict(os.environ, XLA_FLAGS=flags), capture_output=True,
        )
        if probe.returncode == 0:
            os.environ["XLA_FLAGS"] = flags

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# Set here and as environment variables, which JAX reads at import: the tests' subprocesses
# (the command line, notebooks, float32 and multi-device runs) share the cache too.
_CACHE_SETTINGS = {
    "jax_compilation_cache_dir": os.environ["VI_JAX_TEST_XLA_CACHE"],
    "jax_persistent_cache_min_compile_time_secs": 0.0,
    "jax_persistent_cache_min_entry_size_bytes": 0,
}
for _name, _value in _CACHE_SETTINGS.items():
    os.environ[_name.upper()] = str(_value)
    jax.config.update(_name, _value)

# Start the backend now, with the flags above: a test that runs the command line in-process
# (``vi_jax.cli.main``, which asks for the loop option in its own process) then leaves XLA_FLAGS,
# and with them the plans of every later test in this worker, as they are.
jax.devices()


@pytest.fixture
def fresh_programs():
    """For a test that switches something read at trace time: ``jax.clear_caches()`` before the
    test, at each call of the returned function (the next call traces anew) and after the test (no
    other test reuses a program traced with the switch)."""
    jax.clear_caches()
    yield jax.clear_caches
    jax.clear_caches()


def pytest_collection_modifyitems(items):
    """The tests using :func:`fresh_programs` run last: a clear drops every program its worker has
    traced, and the tests after it would trace them again."""
    items.sort(key=lambda item: "fresh_programs" in item.fixturenames)


def pytest_unconfigure(config):
    if _CACHE_OWNER and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ.pop("VI_JAX_TEST_XLA_CACHE"), ignore_errors=True)
