"""Bad input gets a clear ValueError naming the argument, the expectation and the value."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj

MODEL = vj.models.UnderwaterVehicle()
X0 = MODEL.initial_state()


def simulate(**overrides):
    kwargs = dict(system=MODEL, x0=X0, h=0.01, n_steps=5)
    kwargs.update(overrides)
    return vj.simulate(kwargs.pop("system"), kwargs.pop("x0"), kwargs.pop("h"), kwargs.pop("n_steps"), **kwargs)


def with_state(**fields):
    return vj.State(**{**dict(g=X0.g, xi=X0.xi, q=X0.q, qdot=X0.qdot), **fields})


SIMULATE_CASES = [
    ("h", dict(h=0.0), r"h: expected a finite number > 0, got 0"),
    ("h", dict(h=-0.01), r"h: expected a finite number > 0"),
    ("h", dict(h=float("nan")), r"h: expected a finite number > 0, got nan"),
    ("h", dict(h=float("inf")), r"h: expected a finite number > 0, got inf"),
    ("h", dict(h=jnp.ones(2)), r"h: expected shape \(\), got shape \(2,\)"),
    ("n_steps", dict(n_steps=0), r"n_steps: expected an integer ≥ 1, got 0"),
    ("n_steps", dict(n_steps=2.5), r"n_steps: expected an integer ≥ 1, got 2.5"),
    ("n_steps", dict(n_steps=True), r"n_steps: expected an integer ≥ 1, got True"),
    ("tau", dict(tau="rodrigues"), r"tau: expected one of \['cayley', 'exp'\] .*got 'rodrigues'"),
    ("order", dict(order=3), r"order: expected one of \(1, 2, 4, 6\), got 3"),
    ("save_every", dict(save_every=0), r"save_every: expected an integer ≥ 1, got 0"),
    ("save_every", dict(save_every=3), r"save_every: expected a divisor of n_steps=5, got 3"),
    ("x0.g", dict(x0=with_state(g=2 * jnp.eye(3))), r"x0.g: expected an element of SO3 .*membership error 12\.2"),
    ("x0.g", dict(x0=with_state(g=jnp.eye(4))), r"x0.g: expected shape \(3, 3\), got shape \(4, 4\)"),
    ("x0.g", dict(x0=with_state(g=jnp.full((3, 3), jnp.nan))), r"x0.g: expected finite values"),
    ("x0.xi", dict(x0=with_state(xi=jnp.zeros(4))), r"x0.xi: expected shape \(3,\), got shape \(4,\)"),
    ("x0.xi", dict(x0=with_state(xi=jnp.array([0.0, jnp.inf, 0.0]))), r"x0.xi: expected finite values"),
    ("x0.q", dict(x0=with_state(q=jnp.array([0.0, jnp.nan, 1.0]))), r"x0.q: expected finite values"),
    ("x0.qdot", dict(x0=with_state(qdot=jnp.zeros(2))), r"x0.qdot: expected shape \(3,\), got shape \(2,\)"),
    ("x0", dict(x0=with_state(q=None, qdot=None)), r"x0: this system has additional dynamics; expected x0.q and x0.qdot"),
    ("x0", dict(x0=(X0.g, X0.xi)), r"x0: expected a vi_jax.State"),
    ("x0.xi", dict(x0=with_state(xi=jnp.array([1, 2, 3]) + 0j)), r"x0.xi: expected a real numeric array, got dtype complex"),
    ("system", dict(system="vehicle"), r"system: expected a vi_jax system \(AbstractSystem\), got str"),
    ("parameters", dict(system=eqx.tree_at(lambda m: m.buoyancy, MODEL, jnp.nan)), r"system parameters: expected finite values"),
]


@pytest.mark.parametrize("argument, overrides, message", SIMULATE_CASES, ids=[c[0] + ":" + c[2][:25] for c in SIMULATE_CASES])
def test_simulate_rejects_bad_input(argument, overrides, message):
    with pytest.raises(ValueError, match=message):
        simulate(**overrides)


MODEL_CASES = [
    (lambda: vj.models.UnderwaterVehicle(mass=-1.0), r"mass: expected a finite number > 0, got -1"),
    (lambda: vj.models.UnderwaterVehicle(mass=float("nan")), r"mass: expected a finite number > 0, got nan"),
    (lambda: vj.models.UnderwaterVehicle(inertia=(1.0, -2.0, 1.0)), r"inertia: expected symmetric positive definite"),
    (lambda: vj.models.UnderwaterVehicle(inertia=[[1.0, 2.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), r"inertia: expected symmetric positive definite"),
    (lambda: vj.models.UnderwaterVehicle(inertia=(1.0, 2.0)), r"inertia: expected shape \(3, 3\), got shape \(2, 2\)"),
    (lambda: vj.models.UnderwaterVehicle(added_mass=(-200.0, 0.0, 0.0)), r"added_mass \+ mass·I: expected symmetric positive definite"),
    (lambda: vj.models.UnderwaterVehicle(buoyancy_offset=(0.0, 0.0)), r"buoyancy_offset: expected shape \(3,\), got shape \(2,\)"),
    (lambda: vj.models.UnderwaterVehicle(gravity=0.0), r"gravity: expected a finite number > 0, got 0"),
    (lambda: vj.models.UnderwaterVehicle(buoyancy=jnp.nan), r"buoyancy: expected finite values, got .*nan"),
    (lambda: MODEL.initial_state(R0=jnp.diag(jnp.array([1.0, 1.0, -1.0]))), r"R0: expected an element of SO3"),
    (lambda: MODEL.initial_state(v0=jnp.array([jnp.nan, 0.0, 0.0])), r"v0: expected finite values"),
    (lambda: MODEL.initial_state(omega0=jnp.zeros(2)), r"omega0: expected shape \(3,\), got shape \(2,\)"),
    (lambda: vj.models.RigidBody(inertia=(0.5, 0.0, 1.0)), r"inertia: expected symmetric positive definite"),
    (lambda: vj.models.HeavyTop(mass=0.0), r"mass: expected a finite number > 0, got 0"),
    (lambda: vj.System(vj.lie.SO3(), "not callable"), r"lagrangian: expected a callable"),
    (lambda: vj.System("SO3", lambda *a: 0.0), r"group: expected a vi_jax.lie group"),
    (lambda: vj.lie.SOn(1), r"SOn: n must be an integer ≥ 2, got 1"),
]


@pytest.mark.parametrize("make, message", MODEL_CASES, ids=[c[1][:30] for c in MODEL_CASES])
def test_models_reject_bad_input(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_newton_failure_raises_with_step_and_is_flagged_without_throw():
    """A forced failure (one Newton iteration allowed with an impossible tolerance)."""
    with pytest.raises(vj.NewtonFailure, match=r"step 0 .*relative residual .* after 1 iterations"):
        simulate(max_newton_iterations=1, rtol=1e-30)
    sol = simulate(max_newton_iterations=1, rtol=1e-30, throw=False)
    assert not bool(sol.succeeded)
    assert int(sol.result[1]) == 1  # the failing step: Newton's iteration budget
    assert np.all(np.asarray(sol.result[2:]) == 2)  # nothing continues from an unsolved state
    assert np.all(np.isnan(np.asarray(sol.q[1:])))


def test_exp_singular_set_is_reported():
    """h|ω| beyond π with τ = exp is an error, not aliased numbers; Cayley has no such limit."""
    body = vj.models.RigidBody()
    x0 = body.initial_state(omega0=(0.0, 0.0, 40.0))
    with pytest.raises(vj.NewtonFailure, match="singular set of τ = exp"):
        vj.simulate(body, x0, 0.1, 3, tau="exp")
    assert bool(vj.simulate(body, x0, 0.1, 3, tau="cayley").succeeded)


def test_cli_reports_bad_input_in_one_line(capsys):
    from vi_jax.cli import main

    assert main(["simulate", "underwater", "--h", "-1", "--steps", "2", "--out", "/tmp/vi_jax_cli_bad", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("vi-jax: error: h: expected a finite number > 0")
