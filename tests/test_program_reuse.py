"""``vj.simulate`` on concrete inputs compiles one program per scene and scheme for every run of
up to 1024 saved nodes: the step counts are traced integers, the saved-node buffer has a
minimum capacity (a new program costs seconds of compilation, ``python benchmarks/capacity.py``);
orders 2, 4 and 6 share one program (their sub-step fractions are traced)."""

import logging

import jax
import numpy as np

import vi_jax as vj


def test_runs_of_different_lengths_share_one_program(caplog):
    model = vj.models.RigidBody()
    x0 = model.initial_state()
    vj.simulate(model, x0, 0.01, 10)  # compiles (or finds) the program
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        long = vj.simulate(model, x0, 0.01, 1024)
        sparse = vj.simulate(model, x0, 0.01, 3072, save_every=3)
    assert long.g.shape[0] == sparse.g.shape[0] == 1025
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(_simulate_loop)")]
    assert compiled == []


def test_orders_2_4_and_6_share_one_program(caplog):
    """The trapezoid compositions' sub-step fractions are traced data: one program for the three."""
    model = vj.models.HeavyTop()  # as in tests/test_orders.py, whose runs this one shares
    x0 = model.initial_state()
    runs = {2: vj.simulate(model, x0, 0.05, 20, order=2)}
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        runs.update({order: vj.simulate(model, x0, 0.05, 20, order=order) for order in (4, 6)})
    finals = [np.asarray(sol.g[-1]) for sol in runs.values()]
    assert not any(np.array_equal(a, b) for a, b in zip(finals, finals[1:]))  # different schemes ran
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(_simulate_loop)")]
    assert compiled == []
