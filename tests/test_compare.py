"""Smoke test of the error-against-run-time study (vi_jax/studies/work_precision.py) on tiny sizes."""

import dataclasses
import json
import math

from vi_jax.studies import work_precision as _compare

# The quick study shrunk to one program per peer: the long-horizon run has the work-precision
# run's step count and saved nodes, so the two share compiled programs.
TINY = dataclasses.replace(
    _compare.QUICK,
    T=5.0,
    schemes=(("cayley", 1), ("splitting", 4)),
    steps={"vehicle": {1: (100,), ("splitting", 4): (100,)}},
    tolerances={"dopri8": (1e-6,)},
    long_T=5.0,
    long_steps=100,
    long_schemes=(("cayley", 1, 100), ("splitting", 4, 100)),
    long_tolerances={"dopri8": (1e-6,)},
    n_save=1,
)
VI_JAX = {"vi_jax cayley order 1", "vi_jax splitting order 4"}
PEERS = VI_JAX | {"diffrax Dopri8 (PID)", "diffrax RK4 (fixed step)"}


def _finite(x):
    return isinstance(x, (int, float)) and math.isfinite(x)


def test_tiny_study_writes_json_and_plots(tmp_path):
    _compare.run_study(TINY, tmp_path, progress=False)
    result = json.loads((tmp_path / "work_precision.json").read_text())

    wp = result["work_precision"]["vehicle"]
    assert set(wp["peers"]) == PEERS
    for rows in wp["peers"].values():
        for row in rows:
            assert row["succeeded"]
            assert all(_finite(row[k]) for k in ("compile_s", "first_s", "median_s", "error"))
            assert len(row["samples_s"]) == TINY.repeats
    assert wp["reference"]["difference_from_rtol_10x"] < 1e-10
    assert len(wp["goal"]["accuracies"]) == len(_compare.ACCURACIES)

    long = result["long_horizon"]["peers"]
    assert set(long) == PEERS
    for rows in long.values():
        for row in rows:
            assert all(_finite(row[k]) for k in ("median_s", "energy_error", "kelvin_noether_error", "group_drift"))
    for peer in VI_JAX:
        (vi,) = long[peer]
        assert vi["kelvin_noether_error"] <= 1e-12
        assert vi["group_drift"] <= 1e-12
    for peer in PEERS - VI_JAX:
        assert min(r["kelvin_noether_error"] for r in long[peer]) > 1e-12
    assert set(result["long_horizon"]["energy_vs_time"]) == PEERS

    for name in ("work_precision.png", "long_horizon.png", "energy_vs_time.png"):
        assert (tmp_path / name).stat().st_size > 10_000
