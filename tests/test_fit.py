"""Fitting the vehicle's parameters on grid observations: exact recovery from noise-free data,
recovery within the reported uncertainty from noisy data (the initial state estimated with the
parameters), the identifiability structure of eq. (62), the parametrisation's constraints,
Levenberg–Marquardt as an optax transformation, the CLI."""

import argparse
import functools
import json

import jax.numpy as jnp
import numpy as np
import optax
import pytest

import vi_jax as vj
from vi_jax.fitting import Observations, Parametrisation, fit, identifiability, levenberg_marquardt, synthesize
from vi_jax.fitting._fit import DEFAULT_FREE, as_telemetry
from vi_jax.fitting._parametrisation import OFFSET_SCALE, PARAMETERS, FreeParameters
from vi_jax.fitting._shooting import Layout, residuals_and_jacobian, samples_of
from vi_jax.cli.fit import add_fit_arguments, run_fit

TRUTH = vj.models.UnderwaterVehicle()
X0 = TRUTH.initial_state()
H, N_STEPS, SAVE_EVERY = 0.05, 400, 10  # 20 s, 40 samples
SIGMA_Q, SIGMA_R = 0.01, 0.01
GUESS = vj.models.UnderwaterVehicle(
    added_mass=(80.0, 55.0, 90.0), inertia=(4.5, 6.5, 5.0), buoyancy_offset=(0.003, -0.004, -0.012)
)
FREE_INDICES = Parametrisation(TRUTH).indices(DEFAULT_FREE)
TRUE_VALUES = np.asarray(Parametrisation(TRUTH).values(TRUTH))[FREE_INDICES]


@functools.lru_cache
def observations(noisy):
    if noisy:
        return synthesize(TRUTH, X0, H, N_STEPS, save_every=SAVE_EVERY, sigma_position=SIGMA_Q, sigma_attitude=SIGMA_R, seed=3)
    exact = vj.simulate(TRUTH, X0, H, N_STEPS, save_every=SAVE_EVERY)
    return Observations(exact.q, exact.R, H, SAVE_EVERY, SIGMA_Q, SIGMA_R)


def test_noise_free_data_recover_the_true_parameters():
    """From a guess 20–30 % off in the added masses and inertias (and mm off in the offset), the
    initial state guessed from the data; every stage stops once the loss is at round-off (at most
    one iteration there each: the Gauss–Newton step's size, not the round-off loss, ends it)."""
    result = fit(observations(False), None, GUESS)
    assert result.converged
    assert np.sum(result.loss_history <= 1e-20) <= len(result.stage_starts)
    assert result.labels == [f"added_mass[{i},{i}]" for i in range(3)] + [f"inertia[{i},{i}]" for i in range(3)] + [
        f"buoyancy_offset[{i}]" for i in range(3)
    ]
    scale = np.where(TRUE_VALUES != 0, np.abs(TRUE_VALUES), OFFSET_SCALE)
    assert np.max(np.abs(result.values - TRUE_VALUES) / scale) <= 1e-8
    assert result.loss <= 1e-20
    for fitted, true in ((result.x0.g, X0.g), (result.x0.xi, X0.xi), (result.x0.q, X0.q), (result.x0.qdot, X0.qdot)):
        np.testing.assert_allclose(fitted, true, rtol=0, atol=1e-9)


def test_noisy_data_recover_the_parameters_within_the_reported_uncertainty():
    result = fit(observations(True), X0, GUESS)
    assert result.converged
    z = (result.values - TRUE_VALUES) / result.std
    assert np.all(np.abs(z) <= 3.5), z
    mahalanobis = float((result.values - TRUE_VALUES) @ np.linalg.solve(result.covariance, result.values - TRUE_VALUES))
    assert mahalanobis <= 27.9  # χ²₉ quantile 0.999
    # The stated noise levels are the data's: χ² per degree of freedom ≈ 1 (246 − 9 − 12 dof,
    # the initial state estimated too; ±0.28 is ±3 standard deviations of χ²/225).
    assert 0.72 <= result.reduced_chi2 <= 1.28
    assert set(result.channels) == {"position", "attitude"}
    for row in result.channels.values():
        assert row["observed_components"] == 41 * 3 and 0.8 <= row["rms_whitened"] <= 1.2
    # The errors are real: noise moves the estimate (by ~1σ), not by round-off.
    assert np.max(np.abs(z)) >= 0.1


def test_identifiability_follows_the_scaling_symmetry_of_the_lagrangian():
    """ℓ depends on the parameters through mI + M_A, mg − B, B·r and J, and scaling all of them
    leaves the motion unchanged: kinematic data identify 9 of the 11 numbers; the two null
    directions are the scaling and the trade of mass between m and B at fixed mg − B, and with m
    and B known everything else is identifiable."""
    obs = observations(True)
    report = identifiability(TRUTH, X0, obs, estimate_state=False)
    for observed in ("position", "attitude", "position + attitude"):
        assert report[f"known: none; observed: {observed}"]["rank"] == 9
        assert report[f"known: mass; observed: {observed}"]["rank"] == 9
        both = report[f"known: mass, buoyancy; observed: {observed}"]
        assert both["rank"] == both["parameters"] == 9 and both["not_identifiable"] == []
    # Estimated with the parameters, the initial state (12 numbers) is identified as well.
    joint = identifiability(TRUTH, X0, obs, known=((), ("mass", "buoyancy")))
    assert joint["known: none; observed: position + attitude"]["rank"] == 9 + 12
    assert joint["known: mass, buoyancy; observed: position + attitude"]["not_identifiable"] == []
    mass_known = report["known: mass; observed: position + attitude"]
    assert {"buoyancy_offset[0]", "buoyancy_offset[1]"} <= set(mass_known["identifiable"])
    assert "buoyancy" in mass_known["not_identifiable"]

    param = Parametrisation(TRUTH)
    theta = param.encode(TRUTH)
    model_of = FreeParameters(param, TRUTH, PARAMETERS)
    telemetry = as_telemetry(obs)
    layout = Layout(np.asarray(telemetry.t), 0.0, H, 1, N_STEPS)
    s0 = jnp.concatenate([jnp.zeros(3), X0.xi, X0.q, X0.g.T @ X0.qdot])[None]
    _, J, _, _ = residuals_and_jacobian(theta, s0, X0.g[None], model_of, layout, samples_of(telemetry), 0.0, "squared", "cayley", 1)
    J = np.asarray(J)[:, : theta.size]
    m, g, B = float(TRUTH.mass), float(TRUTH.gravity), float(TRUTH.buoyancy)
    r = np.asarray(TRUTH.buoyancy_offset)
    added = np.diag(np.asarray(TRUTH.added_mass))
    # θ = (log m, log M_A,ii, log J_ii, log B, r / OFFSET_SCALE)
    scaling = np.concatenate([[1.0], np.ones(3), np.ones(3), [1.0], np.zeros(3)])
    trade = np.concatenate([[1 / m], -1 / added, np.zeros(3), [g / B], -g / B * r / OFFSET_SCALE])
    generic = np.random.default_rng(0).normal(size=theta.size)
    size = lambda v: np.linalg.norm(J @ v) / (np.linalg.norm(J, 2) * np.linalg.norm(v))  # noqa: E731
    assert size(scaling) <= 1e-9 and size(trade) <= 1e-9
    assert size(generic) >= 1e-3


def test_parametrisation_keeps_matrices_symmetric_positive_definite():
    param = Parametrisation(TRUTH, "full")
    assert len(param.labels()) == 1 + 6 + 6 + 1 + 3
    theta = param.encode(TRUTH)
    np.testing.assert_allclose(param.values(param.decode(theta)), param.values(TRUTH), rtol=1e-14, atol=1e-16)
    for seed in range(5):
        model = param.decode(theta + jnp.asarray(np.random.default_rng(seed).normal(size=theta.size)))
        for M in (model.added_mass, model.inertia):
            M = np.asarray(M)
            assert np.array_equal(M, M.T) and np.min(np.linalg.eigvalsh(M)) > 0
        assert float(model.mass) > 0 and float(model.buoyancy) > 0


def test_levenberg_marquardt_transformation_solves_least_squares():
    """On r(x) = Ax − b: every accepted step contracts the error by the damping's factor and the
    iteration reaches the least-squares solution to the round-off of the normal equations; a step
    that would raise the loss is rejected with a larger damping."""
    rng = np.random.default_rng(1)
    A, b = jnp.asarray(rng.normal(size=(20, 4))), jnp.asarray(rng.normal(size=20))
    value_fn = lambda x: 0.5 * jnp.sum((A @ x - b) ** 2)  # noqa: E731
    x_star = jnp.linalg.lstsq(A, b)[0]
    # δ = −(AᵀA + λD)⁻¹Aᵀr with D = diag(AᵀA): in the D½-weighted norm the error e = x − x* obeys
    # e⁺ = λ(B + λI)⁻¹e, B = D^-½ AᵀA D^-½, so it shrinks by at least λ/(λ + μ_min(B)) per step.
    AtA = np.asarray(A.T @ A)
    d_half = np.sqrt(np.diag(AtA))
    mu_min = np.linalg.eigvalsh(AtA / np.outer(d_half, d_half))[0]
    norm = lambda x: float(np.linalg.norm(d_half * np.asarray(x - x_star)))  # noqa: E731
    # Floor: a step is accepted only if it lowers the loss L in floating point, so progress stops
    # once the possible decrease ½‖e‖²_B ≥ μ_min‖e‖²/2 falls below the loss's round-off (a few
    # ε·L): ‖e‖ ≲ √(2·4ε·L*/μ_min); and the normal equations lose cond(A)² ε (Higham, §20.4).
    eps = np.finfo(np.float64).eps
    floor = max(
        np.sqrt(2 * 4 * eps * float(value_fn(x_star)) / mu_min),
        10 * np.linalg.cond(np.asarray(A)) ** 2 * eps * norm(jnp.zeros(4)),
    )
    opt = levenberg_marquardt(damping=1e-3, max_step=np.inf)
    x, state = jnp.zeros(4), opt.init(jnp.zeros(4))
    for _ in range(20):
        lam, before = float(state.damping), norm(x)
        updates, state = opt.update(None, state, x, residuals=A @ x - b, jacobian=A, value_fn=value_fn, value=value_fn(x))
        x = optax.apply_updates(x, updates)
        assert norm(x) <= lam / (lam + mu_min) * before * (1 + 1e-6) or before <= floor
    assert norm(x) <= floor
    damping = float(state.damping)
    updates, state = opt.update(None, state, x, residuals=A @ x - b, jacobian=A, value_fn=value_fn, value=value_fn(x) - 1.0)
    assert np.all(np.asarray(updates) == 0) and float(state.damping) == pytest.approx(4 * damping)


def test_cli_writes_parameters_and_loss_curve(tmp_path, capsys):
    parser = add_fit_arguments(argparse.ArgumentParser())
    args = parser.parse_args(
        ["--h", str(H), "--steps", str(N_STEPS), "--save-every", str(SAVE_EVERY), "--seed", "3", "--max-steps", "2"]
        + ["--out", str(tmp_path), "--no-progress"]
    )
    run_fit(args)
    report = json.loads((tmp_path / "fit.json").read_text())
    assert (tmp_path / "loss.png").stat().st_size > 10_000
    fitted, std, truth, guess = report["fit"]["parameters"], report["fit"]["std"], report["truth"], report["guess"]
    assert set(fitted) == set(truth) == set(std) == set(guess) and len(fitted) == 9
    assert 0 < report["fit"]["iterations"] <= 2 * (len(report["settings"]["continuity"]) + 1)  # ≤ 2 per stage
    # Plumbing only: two steps per multiple-shooting stage need not move every parameter towards
    # the truth (the stages trade parameters against segment states); fit quality is tested above.
    assert all(np.isfinite(v) for v in fitted.values()) and np.isfinite(report["fit"]["reduced_chi2"])
    assert report["fit"]["identifiability"]["not_identifiable"] == []
    assert set(report["fit"]["residuals"]) == {"position", "attitude"}
    for figure in ("channels.png", "residuals.png"):
        assert (tmp_path / figure).stat().st_size > 10_000
    assert "reduced χ²" in capsys.readouterr().out


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(free=("mass", "speed")), r"free: expected distinct names from"),
        (dict(continuity=(1.0, 0.0)), r"continuity: expected finite weights > 0"),
        (dict(loss="l1"), r"loss: expected one of \('squared', 'huber', 'cauchy'\), got 'l1'"),
        (dict(segments=0), r"segments: expected an integer ≥ 1, got 0"),
        (dict(matrices="dense"), r"matrices: expected one of \('diagonal', 'full'\), got 'dense'"),
        (dict(max_steps=0), r"max_steps: expected an integer ≥ 1, got 0"),
    ],
)
def test_fit_rejects_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        fit(observations(False), X0, GUESS, **kwargs)


def test_observations_reject_bad_input():
    q, R = np.zeros((5, 3)), np.tile(np.eye(3), (5, 1, 1))
    with pytest.raises(ValueError, match=r"q: expected shape \(n \+ 1, 3\) with n ≥ 1, got shape \(5, 2\)"):
        Observations(q[:, :2], R, 0.1, 1, 0.01, 0.01)
    with pytest.raises(ValueError, match=r"R: expected shape \(5, 3, 3\), got shape \(4, 3, 3\)"):
        Observations(q, R[:4], 0.1, 1, 0.01, 0.01)
    with pytest.raises(ValueError, match=r"sigma_position: expected a finite number > 0, got 0"):
        Observations(q, R, 0.1, 1, 0.0, 0.01)
