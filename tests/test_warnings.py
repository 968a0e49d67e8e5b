"""Runs that are meaningless or needlessly slow are never silent: ``vj.simulate``, ``vj.ensemble``
(per member) and the beam's time march warn when their own energy error says the result is meaningless (``vj.AccuracyWarning``;
the command line says so on stderr and exits 3), a sound run says nothing, and a single trajectory
on an accelerator warns once (``vj.PerformanceWarning``)."""

import warnings

import jax
import jax.numpy as jnp
import pytest

import vi_jax as vj
from vi_jax._accuracy import MEANINGLESS_ENERGY_ERROR, energy_error
from vi_jax.cli import MEANINGLESS_EXIT, main


def test_energy_error_is_relative_to_the_initial_energy_over_the_finite_values():
    assert energy_error(jnp.asarray([2.0, 2.5, 1.0])) == pytest.approx(0.5)
    assert energy_error(jnp.asarray([2.0, 2.2, jnp.nan])) == pytest.approx(0.1)  # a failure's NaN: reported by result
    # E₀ = 0: measured against the largest |E| along the run.
    assert energy_error(jnp.asarray([0.0, 1.0, -3.0])) == pytest.approx(1.0)


def test_simulate_warns_on_a_meaningless_step_and_not_on_a_sound_one():
    """h = 1.7 s: every step solves its equations, the energy error reaches ~0.7 (a meaningless
    run: a warning). h = 10⁶ s: the second step does not solve them (Newton on ω with ν solved
    first from eq. 74; Newton on all six unknowns had converged there, meaninglessly): the default
    call raises, and with ``throw=False`` the solved steps' energy error warns."""
    model = vj.models.UnderwaterVehicle()
    with pytest.warns(vj.AccuracyWarning, match="Reduce h"):
        sol = vj.simulate(model, model.initial_state(), 1.7, 200)
    assert energy_error(sol.energy) > MEANINGLESS_ENERGY_ERROR
    with pytest.raises(vj.NewtonFailure, match="Reduce h"):
        vj.simulate(model, model.initial_state(), 1e6, 10)
    with pytest.warns(vj.AccuracyWarning, match="Reduce h"):
        sol = vj.simulate(model, model.initial_state(), 1e6, 10, throw=False)
    assert energy_error(sol.energy) > MEANINGLESS_ENERGY_ERROR
    with warnings.catch_warnings():
        warnings.simplefilter("error", vj.AccuracyWarning)
        sol = vj.simulate(model, model.initial_state(), 0.01, 500)
    assert energy_error(sol.energy) < 1e-3


def test_ensemble_counts_the_meaningless_members_and_is_silent_on_sound_ones():
    """A calm member and a fast one (5 m/s through the water) share h = 1 s (the splitting:
    explicit, so the fast member's run finishes, just meaninglessly; a fast spin would not do:
    the sphere piece turns the nearly spherical vehicle almost exactly): one warning naming 1 of
    2 members; the DEP ensemble at h = 0.05 s says nothing."""
    model = vj.models.UnderwaterVehicle()
    members = vj.vary(model.initial_state(), qdot=jnp.array([[0.1, 0.1, 0.8], [5.0, 0.0, 0.0]]))
    with pytest.warns(vj.AccuracyWarning, match="1 of 2 members") as record:
        sol = vj.ensemble(model, members, 1.0, 200, scheme="splitting")
    assert len(record) == 1
    errors = energy_error(sol.energy)
    assert errors[0] < MEANINGLESS_ENERGY_ERROR < errors[1]
    with warnings.catch_warnings():
        warnings.simplefilter("error", vj.AccuracyWarning)
        vj.ensemble(model, members, 0.05, 200)


def test_cli_flags_a_meaningless_run_and_passes_a_sound_one(tmp_path, capsys):
    code = main(["simulate", "underwater", "--h", "1.7", "--steps", "200", "--out", str(tmp_path / "bad"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == MEANINGLESS_EXIT and "vi-jax: warning:" in err and "energy error" in err
    assert (tmp_path / "bad" / "trajectory.npz").exists()  # written for inspection
    code = main(["simulate", "underwater", "--steps", "500", "--out", str(tmp_path / "good"), "--no-progress"])
    assert code == 0 and "warning" not in capsys.readouterr().err


def test_beam_time_march_warns_on_a_step_past_its_stability_limit():
    model = vj.models.GeometricallyExactBeam()
    n = 6
    ds = float(model.length) / n
    g0, xi0 = model.initial_state(n)
    dt_stable = float(model.stable_time_step(ds))
    with warnings.catch_warnings():
        warnings.simplefilter("error", vj.AccuracyWarning)
        vj.multisymplectic.time_march(model, g0, xi0=xi0, dt=0.5 * dt_stable, ds=ds, n_steps=20)
    with pytest.warns(vj.AccuracyWarning):  # the same program (the step count is static; Δt is data)
        sol = vj.multisymplectic.time_march(model, g0, xi0=xi0, dt=1.2 * dt_stable, ds=ds, n_steps=20)
    # 20 % past the stable step the solves still converge (they fail from row ~30), but the energy
    # has grown by orders of magnitude: only the energy says the run is meaningless.
    assert bool(sol.succeeded)


def test_single_trajectory_on_an_accelerator_warns_once_and_device_cpu_runs_on_the_host(monkeypatch):
    from vi_jax.engine import _placement

    monkeypatch.setattr(_placement, "_accelerator_default", lambda: True)
    monkeypatch.setattr(_placement, "_warned", False)
    model = vj.models.RigidBody()
    x0 = model.initial_state()
    with pytest.warns(vj.PerformanceWarning, match="device='cpu'"):
        vj.simulate(model, x0, 0.01, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("error", vj.PerformanceWarning)
        vj.simulate(model, x0, 0.01, 20)  # once only
        sol = vj.simulate(model, x0, 0.01, 20, device="cpu")
    assert sol.g.devices() == {jax.devices("cpu")[0]}
    with pytest.raises(ValueError, match="device"):
        vj.simulate(model, x0, 0.01, 20, device="tpu")
