"""Fitting the underwater vehicle's physical parameters to telemetry.

The model is ``vj.simulate`` itself (any τ and order). Its forward-mode derivatives through the
implicit steps give the Jacobian of the whitened residuals, which drives the optimiser —
Levenberg–Marquardt written as an optax transformation by default, or any optax transformation
fed the gradient Jᵀr — and gives the Fisher information JᵀJ: uncertainties, correlations, and
which parameters the observed channels identify.

A wide basin by multiple shooting (Bock & Plitt 1984; for parameter estimation in ODEs, Bock
1983): the record is cut into ``segments`` pieces (by default one per sample interval, so that
each sample pins the start of its segment) whose initial states are unknowns, first guessed from
the telemetry itself (``_initial_states``), so no segment is integrated far from the data
whatever the parameters. Continuity between segments is a penalty whose weight grows over the
stages ``continuity``, from a tenth of the noise level's pull to a hundred times it, so the
dynamics are imposed gradually (``benchmarks/fit_basin.py`` measured the choices); a last stage
of single shooting from the first segment's state gives the least-squares estimate of the
exact model and its Fisher information. The initial state (attitude, rates, position and
velocity at the first sample) is estimated with the parameters.

Parametrisation (constraints hold by construction): mass, buoyancy and the diagonals of the
added-mass and inertia matrices are exp(θ) (positive); with ``matrices="full"`` each matrix is
LLᵀ with a Cholesky factor whose diagonal is exp(θ) (symmetric positive definite, 6 numbers);
the centre-of-buoyancy offset is ``OFFSET_SCALE``·θ.

Identifiability (seed 000 eq. 62): the motion depends on the parameters only through the mass
matrix mI + M_A, the net weight mg − B, the moment B·r and J, and is unchanged when all four are
scaled together (ℓ → cℓ). Kinematic data therefore identify 9 combinations of the 11 numbers;
with m and B known (weighed in air, displaced volume) M_A, J and r are identifiable, provided
mg ≠ B. :func:`identifiability` reports this from the Jacobian's rank.
"""

import dataclasses
import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import _validation as val
from .._openblas_threads import OVERFLOW_WARNING, threaded_lu_can_overflow
from .._system import State
from ..engine import NewtonFailure, simulate
from ..lie._so3 import so3_exp
from ..models import UnderwaterVehicle
from ._identifiability import STATE_LABELS, _fisher, channel_report, observed_rows
from ._initial_states import estimate_states
from ._levenberg_marquardt import levenberg_marquardt
from ._observations import Observations
from ._parametrisation import FreeParameters, Parametrisation
from ._robust import loss_index
from ._shooting import STATE_SIZE, Layout, residuals_and_jacobian, samples_of, start_state
from ._telemetry import CHANNELS, Telemetry

DEFAULT_FREE = ("added_mass", "inertia", "buoyancy_offset")


MAX_SEGMENTS = 64  # the default number of segments: one per sample interval, at most this


CONTINUITY = (0.1, 1.0, 10.0, 100.0)


STAGE_GTOL = 1e-2

# A stage also ends when the full Gauss–Newton step moves no unknown by more than XTOL·max(|z|, 1)
# (that step is then taken: Gauss–Newton converges quadratically on exact data, so it brings z to
# round-off). On exact data the loss reaches round-off (~1e-27), where the decrease test compares
# round-off with round-off and passed only by chance: the noise-free test's fit spent ~190 of its
# 229 iterations there, and under other compile flags its last stage ran out of iterations. The
# steps at round-off measured 2e-15–7e-13 of max(|z|, 1). MINPACK's xtol plays this part.
XTOL = 1e-10


DEFAULT_H = 0.05


@dataclasses.dataclass(frozen=True)
class FitResult:
    """``model``: the fitted vehicle; ``labels``, ``values`` (the free parameters), ``std`` (one
    standard deviation from the Fisher information at the optimum, the initial state estimated
    jointly; inf where not identifiable), ``covariance`` and ``correlation`` of the values;
    ``x0``: the fitted initial state (at ``t0``); ``loss_history`` (½Σr²/n per iteration;
    ``stage_starts``: the iteration at which each stage began), ``loss``, ``reduced_chi2`` (≈ 1
    when the stated noise levels are right); ``channels``: per observed channel, the number of
    components observed and the RMS of the whitened residuals; ``prediction``: the fitted model
    at the sample times per channel; ``identifiability`` (rank, singular values, null
    directions); ``iterations``, ``converged``."""

    model: UnderwaterVehicle
    labels: list
    values: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    x0: State
    t0: float
    loss_history: np.ndarray
    stage_starts: list
    loss: float
    reduced_chi2: float
    channels: dict
    prediction: dict
    identifiability: dict
    iterations: int
    converged: bool

    def to_dict(self):
        """JSON-ready summary."""
        return {
            "parameters": {k: float(v) for k, v in zip(self.labels, self.values)},
            "std": {k: (float(s) if math.isfinite(s) else None) for k, s in zip(self.labels, self.std)},
            "correlation": {
                "labels": self.labels,
                "matrix": [[(round(float(c), 6) if math.isfinite(c) else None) for c in row] for row in self.correlation],
            },
            "initial_state": {
                "t0": self.t0,
                "R": np.asarray(self.x0.g).tolist(),
                "omega": np.asarray(self.x0.xi).tolist(),
                "q": np.asarray(self.x0.q).tolist(),
                "v": np.asarray(self.x0.qdot).tolist(),
            },
            "loss": self.loss,
            "reduced_chi2": self.reduced_chi2,
            "residuals": self.channels,
            "iterations": self.iterations,
            "converged": self.converged,
            "identifiability": self.identifiability,
        }


def as_telemetry(data) -> Telemetry:
    """:class:`Telemetry` as given, or from grid :class:`Observations` (times k·save_every·h)."""
    if isinstance(data, Telemetry):
        return data
    if isinstance(data, Observations):
        t = np.arange(data.q.shape[0]) * data.save_every * data.h
        return Telemetry(
            t, position=data.q, attitude=data.R, sigma={"position": data.sigma_position, "attitude": data.sigma_attitude}
        )
    raise ValueError(f"data: expected vi_jax Telemetry or Observations, got {type(data).__name__}")


class _Problem(eqx.Module):
    """One stage's least-squares problem: the layout, data, fixed references and the continuity
    weight."""

    model_of: FreeParameters
    layout: Layout
    samples: tuple
    R_ref: jax.Array
    weight: jax.Array
    loss: jax.Array  # the index of the loss in LOSSES, traced: one program for every loss
    tau: str = eqx.field(static=True)
    order: int = eqx.field(static=True)

    def split(self, z):
        n = len(self.model_of.cols)
        return z[:n], z[n:].reshape(self.layout.segments, STATE_SIZE)

    def evaluate(self, z):
        theta, states = self.split(z)
        return residuals_and_jacobian(
            theta, states, self.R_ref, self.model_of, self.layout, self.samples, self.weight, self.loss, self.tau, self.order
        )


def _least_squares(problem, z, optimizer, lm, max_steps, tol, n, history, bar, label):
    """Iterate ``optimizer`` on ``problem`` from z until a full Gauss–Newton step would lower χ²
    by less than ``tol``·χ², or would move no unknown by more than ``XTOL``·max(|z|, 1) (then
    taken); returns z and whether either happened. Every
    evaluation is the one compiled program (residuals and Jacobian); the last is kept, so an
    accepted Levenberg–Marquardt trial is not evaluated twice."""
    state = optimizer.init(z)
    cache = {}

    def evaluate(t):
        key = np.asarray(t).tobytes()
        if key not in cache:
            if len(cache) >= 3:
                cache.pop(next(iter(cache)))
            r, J, ok, _ = problem.evaluate(t)
            cache[key] = (r, J, ok, jnp.where(ok, 0.5 * jnp.sum(r**2) / n, jnp.inf))
        return cache[key]

    value_fn = lambda t: evaluate(t)[3]  # noqa: E731

    for _ in range(max_steps):
        r, J, ok, value = evaluate(z)
        if not bool(ok):
            raise NewtonFailure("fit: the simulation fails at the current parameters; try a closer guess")
        A, g = _normal_equations(J, r)  # shared by the stopping test and the step
        decrease, step, moves = _gauss_newton(A, g, z)
        if float(value) == 0.0 or float(decrease) <= tol * 2 * n * float(value):
            return z, True
        if not bool(moves):
            return z + step, True
        extra = {"normal": A} if lm else {}
        updates, state = optimizer.update(
            g / n, state, z, residuals=r, jacobian=J, value_fn=value_fn, value=value, grad=g / n, **extra
        )
        z = optax.apply_updates(z, updates)
        history.append(float(value))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(stage=label, loss=f"{history[-1]:.4g}")
        if lm and float(state.damping) > 1e12:  # no step lowers the loss: at round-off
            return z, True
    return z, False


# One compiled program each (an eager operation is compiled apiece: a first fit compiled ~280
# small programs for 5.7 s).


@jax.jit
def _normal_equations(J, r):
    """(JᵀJ, Jᵀr)."""
    return J.T @ J, J.T @ r


@jax.jit
def _gauss_newton(A, g, z):
    """The full Gauss–Newton step −A⁺g from z (A = JᵀJ, g = Jᵀr), the decrease of Σr² it
    predicts, gᵀA⁺g (the squared length, in units of σ, of the move to the linearised minimum),
    and whether it moves some unknown by more than ``XTOL``·max(|z|, 1)."""
    step = -jnp.linalg.solve(A + 1e-14 * jnp.max(jnp.diag(A)) * jnp.eye(A.shape[0]), g)
    return -(g @ step), step, jnp.any(jnp.abs(step) > XTOL * jnp.maximum(jnp.abs(z), 1.0))


_rotations = jax.jit(jax.vmap(so3_exp))


def _recentred(states, R_ref):
    """Fold the attitude increments δ into the references (δ = 0 again)."""
    R = np.einsum("nij,njk->nik", np.asarray(R_ref), np.asarray(_rotations(jnp.asarray(states[:, :3]))))
    states = np.array(states)
    states[:, :3] = 0.0
    return states, R


def fit(
    data,
    x0: State | None,
    guess: UnderwaterVehicle,
    *,
    h: float | None = None,
    free=DEFAULT_FREE,
    matrices="diagonal",
    loss="squared",
    segments: int | None = None,
    continuity=CONTINUITY,
    optimizer=None,
    max_steps: int = 100,
    gtol: float = 1e-6,
    tau="cayley",
    order: int = 1,
    rtol: float = 1e-7,
    progress: bool = False,
) -> FitResult:
    """Fit ``guess``'s ``free`` parameters (the others stay as given) and the initial state to
    ``data`` (:class:`Telemetry`, or grid :class:`Observations`), integrating with step ``h``
    (default: the Observations' step, else ``DEFAULT_H``) from the first sample time.

    ``x0``: a first guess of the state at the first sample (None: from the telemetry, zero
    where it shows nothing). ``loss``: ``"squared"``, ``"huber"`` or ``"cauchy"`` on the
    whitened residuals (outliers). ``segments``: multiple-shooting segments (default: one per
    sample interval, at most ``MAX_SEGMENTS``; 1 = single shooting), fitted with the continuity
    penalty weights ``continuity`` in turn, then single shooting. ``optimizer``:
    :func:`levenberg_marquardt` (default) or any optax transformation, which is then fed the
    gradient Jᵀr/n; up to ``max_steps`` iterations per stage, a stage ending when an accepted
    full Gauss–Newton step would lower χ² = Σr² by less than ``gtol``·χ² (``STAGE_GTOL`` before
    the last stage), or would move no unknown by more than ``XTOL``·max(|z|, 1) (that step
    taken): on noisy data the parameters are then within a few hundredths of σ of the minimum,
    on exact data at round-off.
    ``progress=True`` shows a progress bar. Warns where OpenBLAS's threaded LU may overflow its
    thread's stack (``vi_jax/_openblas_threads.py``: Gauss–Newton systems of 100 unknowns or more,
    i.e. more than 7 segments with the default 9 parameters).
    """
    telemetry = as_telemetry(data)
    if h is None:
        h = data.h if isinstance(data, Observations) else DEFAULT_H
    h = float(val.check_positive_scalar("h", h))
    if x0 is not None and not isinstance(x0, State):
        raise ValueError(f"x0: expected a vi_jax.State or None, got {type(x0).__name__}")
    if not isinstance(guess, UnderwaterVehicle):
        raise ValueError(f"guess: expected a vj.models.UnderwaterVehicle, got {type(guess).__name__}")
    max_steps = val.check_int("max_steps", max_steps, 1)
    loss = loss_index(loss)
    continuity = tuple(float(w) for w in continuity)
    if any(not (w > 0 and math.isfinite(w)) for w in continuity):
        raise ValueError(f"continuity: expected finite weights > 0, got {continuity!r}")
    model_of = FreeParameters(Parametrisation(guess, matrices), guess, free)
    labels = model_of.labels()
    t = np.asarray(telemetry.t)
    t0, duration = float(t[0]), float(t[-1] - t[0])
    n_steps = max(1, math.ceil(duration / h - 1e-9))
    if segments is None:
        segments = max(1, min(n_steps, t.size - 1, MAX_SEGMENTS))
    segments = val.check_int("segments", segments, 1)
    system_order = len(labels) + STATE_SIZE * segments  # the largest Gauss–Newton system
    if threaded_lu_can_overflow(system_order):
        warnings.warn(f"vj.fit: {OVERFLOW_WARNING.format(order=system_order)}", RuntimeWarning, stacklevel=2)
    n_unknowns = len(labels) + STATE_SIZE
    if telemetry.n_observed <= n_unknowns:
        raise ValueError(
            f"data: {telemetry.n_observed} observed components for {len(labels)} free parameters and the "
            f"{STATE_SIZE} components of the initial state: expected more observations than unknowns"
        )
    lm = optimizer is None
    optimizer = levenberg_marquardt() if lm else optax.with_extra_args_support(optimizer)
    n_obs = telemetry.n_observed

    # First guesses of every segment's initial state: the telemetry, else a run of the guess.
    layout = Layout(t, t0, h, segments, n_steps)
    if x0 is None:
        x0 = _state_from(estimate_states(telemetry, [t0], _identity_fallback(1)), 0)
    if _fully_observed(telemetry):
        fallback = _identity_fallback(segments)
    else:
        run = simulate(guess, x0, h, segments * layout.steps, save_every=layout.steps, tau=tau, order=order, throw=False)
        fallback = tuple(np.asarray(a)[:-1] for a in (run.R, run.omega, run.q, run.nu))
    states, R_ref = estimate_states(telemetry, layout.start_times(), fallback)

    # The multiple-shooting stages, then single shooting from the first segment's state.
    plan = [(segments, w) for w in continuity] if segments > 1 else []
    plan.append((1, 0.0))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_steps * len(plan), desc="fit", unit="it")
    history, stage_starts = [], []
    samples = samples_of(telemetry)
    theta = model_of.initial()
    converged = False
    for n_seg, weight in plan:
        if n_seg == 1:
            layout, states, R_ref = Layout(t, t0, h, 1, n_steps), states[:1], R_ref[:1]
        problem = _Problem(model_of, layout, samples, jnp.asarray(R_ref), jnp.asarray(weight), jnp.asarray(loss), tau, order)
        stage_starts.append(len(history))
        z = jnp.concatenate([theta, jnp.asarray(states).ravel()])
        label = "single shooting" if n_seg == 1 else f"{n_seg} segments, w={weight:g}"
        tol = gtol if n_seg == 1 else max(gtol, STAGE_GTOL)
        z, converged = _least_squares(problem, z, optimizer, lm, max_steps, tol, n_obs, history, bar, label)
        theta, states = problem.split(z)
        states, R_ref = _recentred(states, R_ref)
    if bar is not None:
        bar.close()

    z = jnp.concatenate([theta, jnp.asarray(states).ravel()])
    problem = eqx.tree_at(lambda p: p.R_ref, problem, jnp.asarray(R_ref))
    r, J, _, prediction = problem.evaluate(z)
    theta = z[: len(labels)]
    n_free, n_z = len(labels), z.size
    D = np.eye(n_z)
    D[:n_free, :n_free] = np.asarray(_physical_jacobian(model_of, theta))[np.asarray(model_of.cols)]
    rows = observed_rows(telemetry.mask, t.size)
    z_labels = labels + STATE_LABELS
    report, cov, std = _fisher(np.asarray(J)[rows], z_labels, D, rtol)
    cov, std = cov[:n_free, :n_free], std[:n_free]
    # What each channel would add: the Jacobian of every channel at every sample (residuals
    # against the model itself, so the attitude rows are linearised at the fit).
    everything = (prediction, {c: jnp.ones_like(m) for c, m in samples[1].items()}, samples[2])
    _, J_all, _, _ = eqx.tree_at(lambda p: p.samples, problem, everything).evaluate(z)
    report = {**channel_report(np.asarray(J_all), {c: telemetry.mask[c] for c in telemetry.channels}, labels, z_labels, rtol), "rank": report["rank"]}
    scale = np.sqrt(np.diag(cov))
    with np.errstate(divide="ignore", invalid="ignore"):
        correlation = np.where(np.isfinite(std)[:, None] & np.isfinite(std)[None], cov / np.outer(scale, scale), np.nan)
    model = model_of(theta)
    residual = np.asarray(r)
    chi2 = float(np.sum(residual**2))
    return FitResult(
        model=model,
        labels=labels,
        values=np.asarray(model_of.param.values(model))[np.asarray(model_of.cols)],
        std=std,
        covariance=cov,
        correlation=correlation,
        x0=start_state(jnp.asarray(states[0]), jnp.asarray(R_ref[0])),
        t0=t0,
        loss_history=np.asarray(history),
        stage_starts=stage_starts,
        loss=0.5 * chi2 / n_obs,
        reduced_chi2=chi2 / max(n_obs - report["rank"], 1),
        channels=_per_channel(residual, telemetry),
        prediction={c: np.asarray(prediction[c]) for c in telemetry.channels},
        identifiability=report,
        iterations=len(history),
        converged=converged,
    )


@eqx.filter_jit
def _physical_jacobian(model_of, theta):
    """∂(physical parameter values)/∂θ_free."""
    return jax.jacfwd(lambda th: model_of.param.values(model_of(th)))(theta)


def _identity_fallback(n):
    return np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))


def _fully_observed(telemetry):
    """Whether every component of position and attitude is observed, so that the first guesses
    of the segment states need no simulation (rates alone give no attitude)."""
    return bool(np.all(telemetry.observed("position")) and np.all(telemetry.observed("attitude")))


def _state_from(estimate, i):
    states, R_ref = estimate
    return start_state(jnp.asarray(states[i]), jnp.asarray(R_ref[i]))


def _per_channel(residual, telemetry):
    """Per given channel: the components observed and the RMS of the whitened (robustified)
    residuals."""
    m = telemetry.t.size
    out = {}
    for i, c in enumerate(CHANNELS):
        if c in telemetry.channels:
            r = residual[3 * m * i : 3 * m * (i + 1)]
            count = float(np.sum(np.asarray(telemetry.mask[c])))
            out[c] = {"observed_components": int(count), "rms_whitened": float(np.sqrt(np.sum(r**2) / max(count, 1)))}
    return out
