"""The single-trajectory programs' compile option (XLA:CPU's elemental emitters, per program):
vi_jax/engine/_compile_options.py."""

import jax
import jax.numpy as jnp
import numpy as np

import vi_jax as vj
from vi_jax.engine import _compile_options as co


def test_an_option_this_xla_does_not_know_is_left_out():
    # What a newer XLA without the emitters' switch answers: the programs then compile plainly.
    assert not co.accepted("xla_cpu_no_such_option_for_vi_jax", False)


def test_the_users_xla_flags_choose_the_emitters(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert not co.elemental_emitters_apply()
    monkeypatch.setenv("XLA_FLAGS", "")
    assert co.elemental_emitters_apply() == co.accepted(co.EMITTERS_FLAG, False)


def test_no_option_under_a_transformation(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "")
    seen = []
    jax.jit(lambda x: seen.append(co.elemental_emitters_apply()) or x)(1.0)
    jax.vmap(lambda x: seen.append(co.elemental_emitters_apply()) or x)(jnp.ones(2))
    jax.grad(lambda x: seen.append(co.elemental_emitters_apply()) or x)(1.0)
    assert seen == [False, False, False]


def test_the_program_follows_the_choice_at_each_call(monkeypatch):
    traced = []

    def double(x):
        traced.append(x.shape)
        return 2 * x

    program = co.single_trajectory_jit(double)
    x = jnp.arange(3.0)
    for choice in (True, False, True, False):
        monkeypatch.setattr(co, "elemental_emitters_apply", lambda choice=choice: choice)
        np.testing.assert_array_equal(program(x), 2 * x)
    assert len(traced) == 2  # one program per choice, each reused


def test_simulate_with_the_option_equals_simulate_without(monkeypatch):
    """The concrete call (the option where this XLA has it), under ``jit`` (never the option)
    and a ``jit`` closing over concrete inputs (the concrete path nested in a trace: no option,
    no error) give the same run to round-off: 200 Cayley steps of a few hundred flops each, so
    the emitters' different fusion can differ by at most a few hundred ulps per step."""
    monkeypatch.setenv("XLA_FLAGS", "")
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    concrete = vj.simulate(model, x0, 0.01, 200, order=2)
    traced = jax.jit(lambda m, x: vj.simulate(m, x, 0.01, 200, order=2))(model, x0)
    closed_over = jax.jit(lambda: vj.simulate(model, x0, 0.01, 200, order=2))()
    for other in (traced, closed_over):
        np.testing.assert_allclose(other.q, concrete.q, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(other.M, concrete.M, rtol=1e-11, atol=1e-11)
