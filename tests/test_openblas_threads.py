"""OpenBLAS's threaded LU under an unlimited stack limit (vi_jax/_openblas_threads.py): when
the condition holds, vj.fit warns before any linear algebra and the command line asks OpenBLAS
for one thread; a finite limit, one CPU or a thread count of 1 clears it; a user's own count
stands. (The crash itself is intermittent, 2 of 20 fresh processes of 200 solves:
``python benchmarks/openblas_threads.py``; not a test.)"""

import os
import resource
import warnings

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


def test_fit_warns_before_its_linear_algebra(unlimited_stack_two_cpus, monkeypatch):
    import vi_jax as vj

    guess = vj.models.UnderwaterVehicle()
    with pytest.warns(RuntimeWarning, match="OPENBLAS_NUM_THREADS=1"), pytest.raises(ValueError, match="data: expected"):
        vj.fit(None, None, guess)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="data: expected"):
            vj.fit(None, None, guess)
