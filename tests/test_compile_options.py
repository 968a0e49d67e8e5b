"""Per-program compile options (single trajectories and the fit's Jacobian: XLA:CPU's elemental
emitters; ensembles' CPU plan: ENSEMBLE_OPTIONS): vi_jax/engine/_compile_options.py."""

import jax
import jax.numpy as jnp
import numpy as np

import vi_jax as vj
from vi_jax.engine import _compile_options as co
from vi_jax.engine import _ensemble


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
        monkeypatch.setattr(co, "options_that_apply", lambda options, choice=choice: dict(options) if choice else {})
        np.testing.assert_array_equal(program(x), 2 * x)
    assert len(traced) == 2  # one program per choice, each reused


def test_the_users_xla_flags_keep_their_ensemble_options(monkeypatch):
    """An option the user's XLA_FLAGS name is left to them; the others still apply."""
    region, width = co.ENSEMBLE_OPTIONS
    monkeypatch.setenv("XLA_FLAGS", f"--{region}=false")
    assert region not in co.options_that_apply(co.ENSEMBLE_OPTIONS)
    assert (width in co.options_that_apply(co.ENSEMBLE_OPTIONS)) == co.accepted(width, co.ENSEMBLE_OPTIONS[width])


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


def test_ensemble_with_its_options_equals_ensemble_without(monkeypatch):
    """The options change copies and vector width, not arithmetic: the CPU plan's concrete call
    with them equals the same call without them bitwise (rigid body and vehicle, order 1, 128
    members in two groups, 100 steps)."""
    monkeypatch.setenv("XLA_FLAGS", "")
    tuned_program = _ensemble._run_loop
    plain_program = co.cpu_options_jit(tuned_program.__wrapped__, {})
    for model in (vj.models.RigidBody(), vj.models.UnderwaterVehicle()):
        x0 = model.initial_state()
        states = vj.vary(x0, xi=np.asarray(x0.xi) * (1 + 0.1 * np.linspace(0, 1, 128))[:, None])
        runs = []
        for program in (tuned_program, plain_program):
            monkeypatch.setattr(_ensemble, "_run_loop", program)
            runs.append(vj.ensemble(model, states, 0.01, 100, save_every=4))
        for a, b in zip(jax.tree.leaves(runs[0]), jax.tree.leaves(runs[1])):
            np.testing.assert_array_equal(a, b)


def test_concrete_calls_trace_newton_without_its_gradient_rule(monkeypatch, fresh_programs):
    """A concrete call's programs (concrete inputs: nothing can differentiate them) trace no
    ``custom_root``, whose tangent solve would be traced for nothing; under ``jit`` the same
    functions keep it (gradient tests: tests/test_gradients.py). The values are the same: the
    concrete runs equal the traced ones to round-off (different loop programs: 300 steps of a
    few hundred flops, a few hundred ulps per step at most)."""
    bound = []
    real = jax.lax.custom_root
    monkeypatch.setattr(jax.lax, "custom_root", lambda *args, **kwargs: bound.append(1) or real(*args, **kwargs))
    fresh_programs()  # trace the programs anew
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    states = vj.vary(x0, xi=np.asarray(x0.xi) * (1 + 0.1 * np.linspace(0, 1, 8))[:, None])
    concrete = vj.simulate(model, x0, 0.01, 300, order=2)
    concrete_members = vj.ensemble(model, states, 0.01, 300, order=2, save_every=4)
    assert bound == []
    traced = jax.jit(lambda x: vj.simulate(model, x, 0.01, 300, order=2))(x0)
    traced_members = jax.jit(lambda s: vj.ensemble(model, s, 0.01, 300, order=2, save_every=4))(states)
    assert bound
    for a, b in ((concrete, traced), (concrete_members, traced_members)):
        for field in ("g", "xi", "M", "energy"):
            np.testing.assert_allclose(getattr(a, field), getattr(b, field), rtol=1e-11, atol=1e-11)


def test_the_fit_jacobian_keeps_newtons_gradient_rule(monkeypatch, fresh_programs):
    """The fit's residual-and-Jacobian program is compiled as a concrete call's programs are
    (the elemental emitters where this XLA has them; the fit tests check what it computes), but
    it differentiates inside itself: traced outside any transformation it keeps Newton's
    implicit-function rule (``custom_root``), which a concrete ``vj.simulate`` call drops."""
    from vi_jax.fitting import Telemetry
    from vi_jax.fitting._parametrisation import FreeParameters, Parametrisation
    from vi_jax.fitting._shooting import Layout, residuals_and_jacobian, samples_of

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    t = np.linspace(0.0, 1.0, 11)
    data = Telemetry(t, position=np.zeros((11, 3)), attitude=np.tile(np.eye(3), (11, 1, 1)), sigma={"position": 0.01, "attitude": 0.01})
    model_of = FreeParameters(Parametrisation(model), model, ("added_mass", "inertia"))
    state = jnp.concatenate([jnp.zeros(3), x0.xi, x0.q, x0.g.T @ x0.qdot])[None]
    args = (model_of.initial(), state, x0.g[None], model_of, Layout(t, 0.0, 0.05, 1, 20), samples_of(data),
            jnp.asarray(0.0), "squared", "cayley", 1)
    bound = []
    real = jax.lax.custom_root
    monkeypatch.setattr(jax.lax, "custom_root", lambda *a, **k: bound.append(1) or real(*a, **k))
    fresh_programs()  # trace the program anew
    residuals_and_jacobian.lower(*args)
    assert bound
