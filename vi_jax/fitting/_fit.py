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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import _validation as val
from ..engine import NewtonFailure, simulate
from .._system import State
from ..lie import SO3
from ..models import UnderwaterVehicle
from ._levenberg_marquardt import levenberg_marquardt

PARAMETERS = ("mass", "added_mass", "inertia", "buoyancy", "buoyancy_offset")
DEFAULT_FREE = ("added_mass", "inertia", "buoyancy_offset")
MATRICES = ("diagonal", "full")
OBSERVED = ("position", "attitude")
OFFSET_SCALE = 0.01  # m per unit of θ for the centre-of-buoyancy offset
STAGES = (0.125, 0.25, 0.5, 1.0)
STAGE_FTOL = 1e-4


class Observations(eqx.Module):
    """Positions ``q`` (n+1, 3) [m] and attitudes ``R`` (n+1, 3, 3) sampled every
    ``save_every`` steps of size ``h`` from t = 0 (row 0: the known initial state), with noise
    standard deviations ``sigma_position`` [m] and ``sigma_attitude`` [rad]."""

    q: jax.Array
    R: jax.Array
    h: float = eqx.field(static=True)
    save_every: int = eqx.field(static=True)
    sigma_position: float = eqx.field(static=True)
    sigma_attitude: float = eqx.field(static=True)

    def __init__(self, q, R, h, save_every, sigma_position, sigma_attitude):
        self.q = val.check_finite("q", val.as_array("q", q))
        self.R = val.check_finite("R", val.as_array("R", R))
        if self.q.ndim != 2 or self.q.shape[1] != 3 or self.q.shape[0] < 2:
            raise ValueError(f"q: expected shape (n + 1, 3) with n ≥ 1, got shape {self.q.shape}")
        val.as_array("R", self.R, (self.q.shape[0], 3, 3))
        self.h = float(val.check_positive_scalar("h", h))
        self.save_every = val.check_int("save_every", save_every, 1)
        self.sigma_position = float(val.check_positive_scalar("sigma_position", sigma_position))
        self.sigma_attitude = float(val.check_positive_scalar("sigma_attitude", sigma_attitude))

    @property
    def n_samples(self):
        return self.q.shape[0] - 1

    @property
    def n_steps(self):
        return self.n_samples * self.save_every


def synthesize(model, x0, h, n_steps, *, save_every, sigma_position, sigma_attitude, seed=0, tau="cayley"):
    """Noisy :class:`Observations` of ``vj.simulate(model, x0, h, n_steps)``: Gaussian position
    noise and attitude noise R·exp(σ ε̂), ε ~ N(0, I) (row 0 stays exact)."""
    sol = simulate(model, x0, h, n_steps, save_every=save_every, tau=tau)
    rng = np.random.default_rng(seed)
    n = sol.q.shape[0]
    noise = lambda sigma: sigma * np.concatenate([np.zeros((1, 3)), rng.normal(size=(n - 1, 3))])  # noqa: E731
    q = np.asarray(sol.q) + noise(sigma_position)
    R = np.einsum("nij,njk->nik", np.asarray(sol.R), np.asarray(jax.vmap(SO3().exp)(jnp.asarray(noise(sigma_attitude)))))
    return Observations(q, R, h, save_every, sigma_position, sigma_attitude)


def _vee_skew(A):
    return 0.5 * jnp.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]], -1)


class Parametrisation(eqx.Module):
    """Unconstrained coordinates θ of all of :data:`PARAMETERS` (see the module docstring);
    ``template`` supplies gravity and, for diagonal matrices, the off-diagonal entries."""

    template: UnderwaterVehicle
    matrices: str = eqx.field(static=True)

    def __init__(self, template, matrices="diagonal"):
        if not isinstance(template, UnderwaterVehicle):
            raise ValueError(f"guess: expected a vj.models.UnderwaterVehicle, got {type(template).__name__}")
        self.template = template
        self.matrices = val.check_choice("matrices", matrices, MATRICES)

    def _matrix_size(self):
        return 3 if self.matrices == "diagonal" else 6

    def labels(self):
        out = []
        for name in PARAMETERS:
            if name in ("mass", "buoyancy"):
                out.append(name)
            elif name == "buoyancy_offset":
                out += [f"buoyancy_offset[{i}]" for i in range(3)]
            elif self.matrices == "diagonal":
                out += [f"{name}[{i},{i}]" for i in range(3)]
            else:
                out += [f"{name}[{i},{j}]" for i, j in zip(*np.tril_indices(3))]
        return out

    def indices(self, free):
        """Positions in θ of the named parameters."""
        free = (free,) if isinstance(free, str) else tuple(free)
        if not free or any(name not in PARAMETERS for name in free) or len(set(free)) != len(free):
            raise ValueError(f"free: expected distinct names from {PARAMETERS}, got {free!r}")
        sizes = {"mass": 1, "buoyancy": 1, "buoyancy_offset": 3}
        out, start = [], 0
        for name in PARAMETERS:
            size = sizes.get(name, self._matrix_size())
            if name in free:
                out += range(start, start + size)
            start += size
        return np.asarray(out)

    def encode(self, model):
        parts = []
        for name in PARAMETERS:
            value = jnp.asarray(getattr(model, name))
            if name in ("mass", "buoyancy"):
                parts.append(jnp.log(value)[None])
            elif name == "buoyancy_offset":
                parts.append(value / OFFSET_SCALE)
            elif self.matrices == "diagonal":
                parts.append(jnp.log(jnp.diag(value)))
            else:
                L = jnp.linalg.cholesky(value)
                parts.append(jnp.where(np.eye(3, dtype=bool), jnp.log(jnp.abs(L)), L)[np.tril_indices(3)])
        return jnp.concatenate(parts)

    def decode(self, theta):
        m, k = self.template, self._matrix_size()
        sizes = {"mass": 1, "buoyancy": 1, "buoyancy_offset": 3}
        start, values = 0, {}
        for name in PARAMETERS:
            t = theta[start : start + sizes.get(name, k)]
            start += sizes.get(name, k)
            if name in ("mass", "buoyancy"):
                values[name] = jnp.exp(t[0])
            elif name == "buoyancy_offset":
                values[name] = OFFSET_SCALE * t
            elif self.matrices == "diagonal":
                old = getattr(m, name)
                values[name] = old - jnp.diag(jnp.diag(old)) + jnp.diag(jnp.exp(t))
            else:
                L = jnp.zeros((3, 3), theta.dtype).at[np.tril_indices(3)].set(t)
                L = jnp.where(np.eye(3, dtype=bool), jnp.exp(L), L)
                values[name] = L @ L.T
        return eqx.tree_at(lambda v: [getattr(v, n) for n in PARAMETERS], m, [values[n] for n in PARAMETERS])

    def values(self, model):
        """Physical values in the order of :meth:`labels`."""
        parts = []
        for name in PARAMETERS:
            value = jnp.asarray(getattr(model, name))
            if name in ("mass", "buoyancy"):
                parts.append(value[None])
            elif name == "buoyancy_offset":
                parts.append(value)
            elif self.matrices == "diagonal":
                parts.append(jnp.diag(value))
            else:
                parts.append(value[np.tril_indices(3)])
        return jnp.concatenate(parts)


def residuals(theta, param, x0, obs, weights, *, tau="cayley", order=1):
    """Whitened residuals times ``weights`` (position rows of samples 1..n, then attitude rows),
    and whether every step of the simulation succeeded."""
    sol = simulate(
        param.decode(theta), x0, obs.h, obs.n_steps, save_every=obs.save_every, tau=tau, order=order, throw=False
    )
    position = (sol.q[1:] - obs.q[1:]) / obs.sigma_position
    attitude = _vee_skew(jnp.einsum("nji,njk->nik", obs.R[1:], sol.R[1:])) / obs.sigma_attitude
    return jnp.concatenate([position.ravel(), attitude.ravel()]) * weights, sol.succeeded


@eqx.filter_jit
def _loss(theta, param, x0, obs, weights, tau, order):
    """½·Σr²/Σw; +inf where a step fails, so that the optimiser backs off."""
    r, ok = residuals(theta, param, x0, obs, weights, tau=tau, order=order)
    return jnp.where(ok, 0.5 * jnp.sum(r**2) / jnp.sum(weights), jnp.inf)


@eqx.filter_jit
def _jacobian(theta, param, x0, obs, weights, tau, order):
    """Residuals, their forward-mode Jacobian w.r.t. all of θ, and success."""
    f = lambda t: residuals(t, param, x0, obs, weights, tau=tau, order=order)  # noqa: E731
    (r, ok), J = f(theta), jax.jacfwd(lambda t: f(t)[0])(theta)
    return r, J, ok


def _weights(obs, fraction=1.0, observed=OBSERVED):
    """1 on the residual rows of the first ``fraction`` of the samples and of the ``observed``
    quantities, 0 elsewhere."""
    observed = (observed,) if isinstance(observed, str) else tuple(observed)
    if not observed or any(o not in OBSERVED for o in observed):
        raise ValueError(f"observed: expected a non-empty subset of {OBSERVED}, got {observed!r}")
    n = obs.n_samples
    rows = np.repeat(np.arange(n) < max(1, round(fraction * n)), 3).astype(float)
    return jnp.asarray(np.concatenate([rows * ("position" in observed), rows * ("attitude" in observed)]))


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


def _fisher(J, labels, D, rtol):
    """Rank, singular values, null directions (in θ) and the covariance of the physical values
    (delta method, Jacobian ``D`` of values w.r.t. θ) from the whitened Jacobian ``J``."""
    J = np.asarray(J)
    _, s, vt = np.linalg.svd(J, full_matrices=True)
    s = np.concatenate([s, np.zeros(J.shape[1] - s.size)])
    rank = int(np.sum(s > rtol * s[0]))
    null = vt[rank:]
    cov_theta = (vt[:rank].T / s[:rank] ** 2) @ vt[:rank]
    cov = D @ cov_theta @ D.T
    identifiable = np.linalg.norm(null, axis=0) <= 1e-4
    std = np.where(identifiable, np.sqrt(np.maximum(np.diag(cov), 0.0)), np.inf)
    report = {
        "rank": rank,
        "parameters": len(labels),
        "singular_values": [float(x) for x in s],
        "identifiable": [k for k, ok in zip(labels, identifiable) if ok],
        "not_identifiable": [k for k, ok in zip(labels, identifiable) if not ok],
        "null_directions_theta": [_readable(v, labels) for v in _echelon(null)],
    }
    return report, cov, std


def _echelon(null):
    """A basis of the null space in reduced row echelon form (pivots on the largest entries):
    each direction moves one parameter by 1 and only non-pivot parameters besides."""
    basis = np.array(null, dtype=float)
    pivots = []
    for row in range(basis.shape[0]):
        free = [c for c in range(basis.shape[1]) if c not in pivots]
        col = free[int(np.argmax(np.abs(basis[row, free])))]
        pivots.append(col)
        basis[row] /= basis[row, col]
        for other in range(basis.shape[0]):
            if other != row:
                basis[other] -= basis[other, col] * basis[row]
    return basis


def _readable(v, labels):
    return {labels[i]: round(float(v[i]), 4) for i in np.argsort(-np.abs(v)) if abs(v[i]) > 1e-4}


def identifiability(model, x0, obs, *, known=((), ("mass",), ("mass", "buoyancy")), matrices="diagonal", tau="cayley", order=1, rtol=1e-7):
    """What ``obs``'s sampling identifies at ``model``: for each set of ``known`` parameters
    (the others free) and for positions only, attitudes only and both, the rank of the whitened
    Jacobian w.r.t. θ (singular values below ``rtol``·s_max count as zero), the identifiable
    parameters (orthogonal to every null direction), the null directions in θ (log coordinates
    for the positive parameters) and standard deviations at ``obs``'s noise levels."""
    param = Parametrisation(model, matrices)
    theta = param.encode(model)
    r, J, ok = _jacobian(theta, param, x0, obs, _weights(obs), tau, order)
    if not bool(ok):
        raise ValueError("model: the simulation of the observed interval fails at these parameters")
    labels = np.asarray(param.labels())
    D_all = np.asarray(jax.jacfwd(lambda t: param.values(param.decode(t)))(theta))
    out = {}
    for fixed in known:
        cols = param.indices(tuple(n for n in PARAMETERS if n not in fixed))
        for observed in (("position",), ("attitude",), ("position", "attitude")):
            rows = np.asarray(_weights(obs, 1.0, observed)) > 0
            names = [str(k) for k in labels[cols]]
            report, _, std = _fisher(np.asarray(J)[np.ix_(rows, cols)], names, D_all[np.ix_(cols, cols)], rtol)
            report["std"] = {k: (float(v) if math.isfinite(v) else None) for k, v in zip(names, std)}
            out[f"known: {', '.join(fixed) or 'none'}; observed: {' + '.join(observed)}"] = report
    return out


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
