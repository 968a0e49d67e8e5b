"""The XLA:CPU loop option requested by the command line (vi_jax/engine/_cpu_tuning.py)."""

import os

from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG, enable_fast_cpu_loops


def test_adds_the_option_to_existing_flags(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert enable_fast_cpu_loops()
    assert os.environ["XLA_FLAGS"] == f"--xla_force_host_platform_device_count=2 {FAST_LOOPS_FLAG}"


def test_leaves_a_users_backend_options_alone(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_extra_options=xla_cpu_foo=1")
    assert not enable_fast_cpu_loops()
    assert os.environ["XLA_FLAGS"] == "--xla_backend_extra_options=xla_cpu_foo=1"
