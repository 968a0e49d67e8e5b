"""The XLA:CPU loop option requested by the command line (vi_jax/engine/_cpu_tuning.py): added
before the first computation, refused with a warning after it (XLA has read its flags; changed
then, they would only change vi_jax's plans), and left alone by an in-process command line."""

import os

import pytest

from vi_jax.engine import _cpu_tuning
from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG, backend_started, enable_fast_cpu_loops


def test_adds_the_option_to_existing_flags(monkeypatch):
    monkeypatch.setattr(_cpu_tuning, "backend_started", lambda: False)  # as before a first computation
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert enable_fast_cpu_loops()
    assert os.environ["XLA_FLAGS"] == f"--xla_force_host_platform_device_count=2 {FAST_LOOPS_FLAG}"


def test_leaves_a_users_backend_options_alone(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_extra_options=xla_cpu_foo=1")
    assert not enable_fast_cpu_loops()
    assert os.environ["XLA_FLAGS"] == "--xla_backend_extra_options=xla_cpu_foo=1"


def test_after_a_computation_it_warns_and_changes_nothing(monkeypatch):
    assert backend_started()  # tests/conftest.py starts the backend
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    with pytest.warns(UserWarning, match="a JAX computation has already run"):
        assert not enable_fast_cpu_loops()
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=2"


def test_the_command_line_in_a_running_session_leaves_the_flags_alone(monkeypatch, capsys, tmp_path):
    """``vi_jax.cli.main`` called in-process (a notebook, these tests) keeps the session's flags:
    before, it appended the option for the rest of the process, and later tests in the same worker
    traced the loop option's plans under default XLA (three failed when the files ran in another
    order, ``pytest --dist loadfile``)."""
    from vi_jax.cli import main

    monkeypatch.setenv("XLA_FLAGS", "")
    assert main(["simulate", "underwater", "--h", "-1", "--steps", "2", "--out", str(tmp_path), "--no-progress"]) == 2
    assert os.environ["XLA_FLAGS"] == ""
    assert "h: expected a finite number > 0" in capsys.readouterr().err
