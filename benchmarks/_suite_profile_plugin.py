"""pytest plugin for ``benchmarks/suite_profile.py``: JAX's compile-phase durations (its
monitoring events) and each test's wall seconds, summed per test, one JSON per xdist worker in
the folder ``VI_JAX_SUITE_PROFILE_DIR`` names."""

import collections
import json
import os
import time
from pathlib import Path

import jax.monitoring
import pytest

_current = {"test": None}
_seconds = collections.defaultdict(lambda: collections.defaultdict(float))


def _duration(event, seconds, **_):
    if _current["test"] is not None:
        name = event.rsplit("/", 1)[-1]
        _seconds[_current["test"]][name] += seconds
        _seconds[_current["test"]]["count_" + name] += 1


def _event(event, **_):
    if _current["test"] is not None:
        _seconds[_current["test"]]["count_" + event.rsplit("/", 1)[-1]] += 1


jax.monitoring.register_event_duration_secs_listener(_duration)
jax.monitoring.register_event_listener(_event)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current["test"] = item.nodeid
    start = time.perf_counter()
    yield
    _seconds[item.nodeid]["wall"] += time.perf_counter() - start
    _current["test"] = None


def pytest_sessionfinish(session):
    worker = os.environ.get("PYTEST_XDIST_WORKER", "controller")
    path = Path(os.environ["VI_JAX_SUITE_PROFILE_DIR"]) / f"{worker}.json"
    path.write_text(json.dumps({test: dict(phases) for test, phases in _seconds.items()}))
