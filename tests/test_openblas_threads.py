"""OpenBLAS's threaded LU under an unlimited stack limit (vi_jax/_openblas_threads.py): when
the condition holds, vj.fit warns before any linear algebra where its Gauss–Newton system is
large enough for OpenBLAS's threaded LU, and the command line asks OpenBLAS
for one thread; a finite limit, one CPU or a thread count of 1 clears it; a user's own count
stands. (The crash itself is intermittent, 2 of 20 fresh processes of 200 solves:
``python benchmarks/openblas_threads.py``; not a test.)"""

import os
import resource
import warnings

import numpy as np
import pytest

from vi_jax import _openblas_threads
from vi_jax._openblas_threads import THREAD_VARIABLES, one_openblas_thread_if_stacks_are_small, threaded_lu_can_overflow


@pytest.fixture
def unlimited_stack_two_cpus(monkeypatch):
    """The condition, whatever this machine's limit: unlimited stack, 2 CPUs, no count set."""
    monkeypatch.setattr(_openblas_threads.sys, "platform", "linux")
    monkeypatch.setattr(resource, "getrlimit", lambda _: (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)


def test_the_condition_and_what_clears_it(unlimited_stack_two_cpus, monkeypatch):
    assert threaded_lu_can_overflow()
    for count, overflows in (("1", False), ("4", True), ("0", True), ("all", True)):
        monkeypatch.setenv("OMP_NUM_THREADS", count)  # read where OpenBLAS's own variables are unset
        assert threaded_lu_can_overflow() is overflows
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")  # the first variable set wins
    assert not threaded_lu_can_overflow()
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    monkeypatch.delenv("OMP_NUM_THREADS")
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert not threaded_lu_can_overflow()
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(resource, "getrlimit", lambda _: (8 * 2**20, resource.RLIM_INFINITY))
    assert not threaded_lu_can_overflow()
    monkeypatch.setattr(resource, "getrlimit", lambda _: (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    monkeypatch.setattr(_openblas_threads.sys, "platform", "darwin")
    assert not threaded_lu_can_overflow()


def test_the_command_line_asks_for_one_thread_unless_a_count_is_set(unlimited_stack_two_cpus, monkeypatch):
    assert one_openblas_thread_if_stacks_are_small()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    assert not threaded_lu_can_overflow()
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    monkeypatch.setenv("GOTO_NUM_THREADS", "2")  # the user's choice stands
    assert not one_openblas_thread_if_stacks_are_small()
    assert "OPENBLAS_NUM_THREADS" not in os.environ


def test_the_command_lines_own_process_runs_one_thread(unlimited_stack_two_cpus, monkeypatch):
    from vi_jax.cli import main
    from vi_jax.engine import _cpu_tuning

    monkeypatch.setattr(_cpu_tuning, "backend_started", lambda: False)  # as in a fresh process
    monkeypatch.setenv("XLA_FLAGS", "")  # restored after the test (main adds the loop option)
    with pytest.raises(SystemExit):
        main(["--no-such-option"])
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"


def test_the_condition_needs_a_system_large_enough_for_the_threaded_lu(unlimited_stack_two_cpus):
    # OpenBLAS's dgetrf runs threaded from 10,000 entries (its interface/lapack/getrf.c)
    assert not threaded_lu_can_overflow(99)
    assert threaded_lu_can_overflow(100)
    assert threaded_lu_can_overflow(777)


def _too_little_data():
    """Five position samples: 15 observed components, fewer than the 9 + 12 unknowns
    of any fit, so vj.fit raises once its arguments are checked, before any linear algebra."""
    from vi_jax.fitting import Telemetry

    t = np.linspace(0.0, 0.4, 5)
    return Telemetry(t, sigma={"position": 0.01}, position=np.zeros((5, 3)))


def test_fit_warns_before_its_linear_algebra_where_its_system_is_large(unlimited_stack_two_cpus, monkeypatch):
    import vi_jax as vj

    guess = vj.models.UnderwaterVehicle()
    # 9 + 12 × 8 = 105 unknowns: threaded; 9 + 12 × 7 = 93 and the default 4 segments: not
    with pytest.warns(RuntimeWarning, match=r"\(105 unknowns\).*OPENBLAS_NUM_THREADS=1"), pytest.raises(ValueError, match="observed components"):
        vj.fit(_too_little_data(), None, guess, segments=8)
    for segments in (None, 1, 7):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(ValueError, match="observed components"):
                vj.fit(_too_little_data(), None, guess, segments=segments)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="observed components"):
            vj.fit(_too_little_data(), None, guess, segments=8)
