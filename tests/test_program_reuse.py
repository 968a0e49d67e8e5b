"""``vj.simulate`` on concrete inputs compiles one program per scene and scheme for every run of
up to 1024 saved nodes: the step counts are traced integers, the saved-node buffer has a
minimum capacity (a new program costs seconds of compilation, ``python benchmarks/capacity.py``);
compositions of orders 4 and 6 share one program (their fractions are traced)."""

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


def test_compositions_of_orders_4_and_6_share_one_program(caplog):
    """Their sub-step fractions are traced data: order 6 runs on order 4's program."""
    model = vj.models.HeavyTop()  # as in tests/test_orders.py, whose runs this one shares
    x0 = model.initial_state()
    four = vj.simulate(model, x0, 0.05, 20, order=4)
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        six = vj.simulate(model, x0, 0.05, 20, order=6)
    assert not np.array_equal(np.asarray(four.g[-1]), np.asarray(six.g[-1]))  # a different scheme ran
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(_simulate_loop)")]
    assert compiled == []
