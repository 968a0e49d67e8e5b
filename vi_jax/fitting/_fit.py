"""Fitting the underwater vehicle's physical parameters to observed positions and attitudes.

The model is ``vj.simulate`` itself (any τ and order). Its forward-mode derivatives (``jacfwd``
through the implicit steps: one tangent per parameter) give the Jacobian of the whitened
residuals, which drives the optimiser — Levenberg–Marquardt written as an optax transformation
by default, or any optax transformation fed the gradient Jᵀr — and gives the Fisher information
JᵀJ: uncertainties, and which parameters the observations identify.

Observations far into the future make the least-squares landscape rugged, so the fit runs in
stages over growing horizons (the first 1/8, 1/4, 1/2 and all of the samples by default), each
started from the last.

Parametrisation (constraints hold by construction): mass, buoyancy and the diagonals of the
added-mass and inertia matrices are exp(θ) (positive); with ``matrices="full"`` each matrix is
LLᵀ with a Cholesky factor whose diagonal is exp(θ) (symmetric positive definite, 6 numbers);
the centre-of-buoyancy offset is ``OFFSET_SCALE``·θ. Residuals are whitened by the observation
noise: position (q_model − q_obs)/σ_q and attitude vee(skew(R_obsᵀR_model))/σ_R (the rotation
vector to first order, smooth at zero).

Identifiability (seed 000 eq. 62): the motion depends on the parameters only through the mass
matrix mI + M_A, the net weight mg − B, the moment B·r and J, and is unchanged when all four are
scaled together (ℓ → cℓ). Kinematic data therefore identify 9 combinations of the 11 numbers;
with m and B known (weighed in air, displaced volume) M_A, J and r are identifiable, provided
mg ≠ B. :func:`identifiability` reports this from the Jacobian's rank.
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import _validation as val
from ..engine import NewtonFailure
from .._system import State
from ..models import UnderwaterVehicle
from ._identifiability import _fisher
from ._levenberg_marquardt import levenberg_marquardt
from ._observations import Observations
from ._parametrisation import Parametrisation
from ._residuals import _jacobian, _loss, _weights

DEFAULT_FREE = ("added_mass", "inertia", "buoyancy_offset")


STAGES = (0.125, 0.25, 0.5, 1.0)


STAGE_FTOL = 1e-4


@dataclasses.dataclass(frozen=True)
class FitResult:
    """``model``: the fitted vehicle; ``labels``, ``values`` (the free parameters), ``std`` (one
    standard deviation from the Fisher information at the optimum, inf where not identifiable),
    ``covariance``; ``loss_history`` (½Σr²/Σw per iteration; ``stage_starts``: the iteration
    at which each horizon began), ``loss``, ``reduced_chi2`` (≈ 1 when the stated noise levels
    are right); ``identifiability`` (rank, singular values, null directions); ``iterations``,
    ``converged``."""

    model: UnderwaterVehicle
    labels: list
    values: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    loss_history: np.ndarray
    stage_starts: list
    loss: float
    reduced_chi2: float
    identifiability: dict
    iterations: int
    converged: bool

    def to_dict(self):
        """JSON-ready summary."""
        return {
            "parameters": {k: float(v) for k, v in zip(self.labels, self.values)},
            "std": {k: (float(s) if math.isfinite(s) else None) for k, s in zip(self.labels, self.std)},
            "loss": self.loss,
            "reduced_chi2": self.reduced_chi2,
            "iterations": self.iterations,
            "converged": self.converged,
            "identifiability": self.identifiability,
        }


def fit(
    obs,
    x0: State,
    guess: UnderwaterVehicle,
    *,
    free=DEFAULT_FREE,
    matrices="diagonal",
    optimizer=None,
    stages=STAGES,
    max_steps: int = 100,
    ftol: float = 1e-12,
    tau="cayley",
    order: int = 1,
    rtol: float = 1e-7,
    progress: bool = False,
) -> FitResult:
    """Fit ``guess``'s ``free`` parameters (the others stay as given) to ``obs`` from the known
    initial state ``x0``.

    ``optimizer``: :func:`levenberg_marquardt` (default) or any optax transformation, which is
    then fed the gradient Jᵀr/Σw; up to ``max_steps`` iterations per stage of ``stages`` (the
    fractions of the samples fitted in turn), a stage ending when an accepted step changes the
    loss by less than ``ftol`` (relative; ``STAGE_FTOL`` before the last stage, which only has to
    provide a start). ``progress=True`` shows a progress bar.
    """
    if not isinstance(obs, Observations):
        raise ValueError(f"obs: expected vi_jax Observations, got {type(obs).__name__}")
    if not isinstance(x0, State):
        raise ValueError(f"x0: expected a vi_jax.State, got {type(x0).__name__}")
    max_steps = val.check_int("max_steps", max_steps, 1)
    stages = tuple(float(s) for s in stages)
    if not stages or any(not 0 < s <= 1 for s in stages) or stages[-1] != 1.0:
        raise ValueError(f"stages: expected fractions in (0, 1] ending with 1, got {stages!r}")
    param = Parametrisation(guess, matrices)
    cols = param.indices(free)
    theta_all = param.encode(guess)
    embed = lambda t: theta_all.at[cols].set(t)  # noqa: E731
    theta = theta_all[cols]
    lm = optimizer is None
    optimizer = levenberg_marquardt() if lm else optax.with_extra_args_support(optimizer)
    state = optimizer.init(theta)
    history, stage_starts, converged = [], [], False
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_steps * len(stages), desc="fit", unit="it")
    cache = {}

    def evaluate(t, weights):
        """Residuals, Jacobian (free columns) and loss at θ_free = t; the last point is kept,
        so an accepted Levenberg–Marquardt trial is not evaluated twice."""
        key = (np.asarray(t).tobytes(), np.asarray(weights).tobytes())
        if cache.get("key") != key:
            r, J, ok = _jacobian(embed(t), param, x0, obs, weights, tau, order)
            value = jnp.where(ok, 0.5 * jnp.sum(r**2) / jnp.sum(weights), jnp.inf)
            cache.update(key=key, value=(r, J[:, cols], ok, value))
        return cache["value"]

    for fraction in stages:
        weights = _weights(obs, fraction)
        tol = ftol if fraction == 1.0 else max(ftol, STAGE_FTOL)
        stage_starts.append(len(history))
        if lm:
            value_fn = lambda t, w=weights: evaluate(t, w)[3]  # noqa: E731
        else:  # a line search may differentiate it
            value_fn = lambda t, w=weights: _loss(embed(t), param, x0, obs, w, tau, order)  # noqa: E731
        converged = False
        for _ in range(max_steps):
            r, J, ok, value = evaluate(theta, weights)
            if not bool(ok):
                raise NewtonFailure("fit: the simulation fails at the current parameters; try a closer guess")
            grad = J.T @ r / jnp.sum(weights)
            updates, state = optimizer.update(
                grad, state, theta, residuals=r, jacobian=J, value_fn=value_fn, value=value, grad=grad
            )
            new_theta = optax.apply_updates(theta, updates)
            history.append(float(value))
            if bar is not None:
                bar.update(1)
                bar.set_postfix(horizon=f"{fraction:g}", loss=f"{history[-1]:.4g}")
            moved = bool(jnp.any(new_theta != theta))
            theta = new_theta
            if moved and float(value - value_fn(theta)) <= tol * float(value) or float(value) == 0.0:
                converged = True
                break
            if lm and float(state.damping) > 1e12:  # no step lowers the loss: at round-off
                converged = True
                break
    if bar is not None:
        bar.close()
    weights = _weights(obs)
    r, J, _ = _jacobian(embed(theta), param, x0, obs, weights, tau, order)
    labels = [param.labels()[i] for i in cols]
    D = np.asarray(jax.jacfwd(lambda t: param.values(param.decode(embed(t))))(theta))[cols]
    report, cov, std = _fisher(np.asarray(J)[:, cols], labels, D, rtol)
    model = param.decode(embed(theta))
    return FitResult(
        model=model,
        labels=labels,
        values=np.asarray(param.values(model))[cols],
        std=std,
        covariance=cov,
        loss_history=np.asarray(history),
        stage_starts=stage_starts,
        loss=float(0.5 * jnp.mean(r**2)),
        reduced_chi2=float(jnp.sum(r**2)) / max(r.size - report["rank"], 1),
        identifiability=report,
        iterations=len(history),
        converged=converged,
    )
