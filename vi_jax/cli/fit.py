"""``vi-jax fit``: recover the underwater vehicle's parameters from observed positions and
attitudes, writing ``DIR/fit.json`` (recovered values, standard deviations, identifiability
report) and ``DIR/loss.png`` (loss per iteration).

Without ``--data`` the observations are synthesized from the Table 1 vehicle (with noise) and
the fit starts from a guess whose free parameters are perturbed by ``--perturb``; with
``--data FILE.npz`` (arrays ``q`` (n+1, 3), ``R`` (n+1, 3, 3), ``omega0``, ``v0`` and scalars
``h``, ``save_every``, ``sigma_position``, ``sigma_attitude``) it starts from Table 1.
"""

import json
from pathlib import Path

import numpy as np

from ..fitting._fit import DEFAULT_FREE
from ..fitting._parametrisation import MATRICES, OFFSET_SCALE, PARAMETERS
from ..plots.fit import plot_loss


def add_fit_arguments(parser):
    """Add the ``vi-jax fit`` options to an argparse (sub)parser."""
    parser.add_argument("--data", type=Path, default=None, help="observations (.npz); default: synthesize them")
    parser.add_argument("--h", type=float, default=0.05, help="time step [s] (synthetic data)")
    parser.add_argument("--steps", type=int, default=400, help="number of steps (synthetic data)")
    parser.add_argument("--save-every", type=int, default=10, help="steps between samples (synthetic data)")
    parser.add_argument("--sigma-position", type=float, default=0.01, help="position noise [m] (synthetic data)")
    parser.add_argument("--sigma-attitude", type=float, default=0.01, help="attitude noise [rad] (synthetic data)")
    parser.add_argument("--seed", type=int, default=0, help="noise and guess seed (synthetic data)")
    parser.add_argument("--perturb", type=float, default=0.1, help="log-scale error of the initial guess (synthetic data)")
    parser.add_argument("--free", nargs="+", default=list(DEFAULT_FREE), choices=PARAMETERS, help="parameters to fit")
    parser.add_argument("--matrices", default="diagonal", choices=MATRICES, help="diagonal or full SPD matrices")
    parser.add_argument("--max-steps", type=int, default=100, help="iterations per horizon stage")
    parser.add_argument("--out", type=Path, default=Path("out/fit"), help="output directory")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return parser


def _perturbed(truth, free, perturb, rng):
    import equinox as eqx
    import jax.numpy as jnp

    guess = truth
    for name in free:
        value = np.asarray(getattr(truth, name))
        if name == "buoyancy_offset":
            new = value + perturb * OFFSET_SCALE * rng.choice([-1.0, 1.0], size=3)
        elif value.ndim == 2:
            new = value @ np.diag(np.exp(perturb * rng.choice([-1.0, 1.0], size=3)))
            new = 0.5 * (new + new.T)
        else:
            new = value * np.exp(perturb * rng.choice([-1.0, 1.0]))
        guess = eqx.tree_at(lambda m, name=name: getattr(m, name), guess, jnp.asarray(new))
    return guess


def _load(path):
    import jax.numpy as jnp

    from ..fitting import Observations
    from .._system import State

    try:
        data = np.load(path)
        obs = Observations(
            data["q"], data["R"], float(data["h"]), int(data["save_every"]),
            float(data["sigma_position"]), float(data["sigma_attitude"]),
        )
        x0 = State(g=jnp.asarray(data["R"][0]), xi=jnp.asarray(data["omega0"]), q=jnp.asarray(data["q"][0]), qdot=jnp.asarray(data["v0"]))
    except (OSError, KeyError) as err:
        raise ValueError(f"data: expected an .npz with q, R, omega0, v0, h, save_every, sigma_position, sigma_attitude; {err}") from err
    return obs, x0


def run_fit(args):
    """Run ``vi-jax fit`` with parsed ``args``; raises ValueError on bad input."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from ..fitting import Parametrisation, fit, identifiability, synthesize
    from ..models import UnderwaterVehicle

    truth = UnderwaterVehicle()
    if args.data is None:
        x0 = truth.initial_state()
        obs = synthesize(
            truth, x0, args.h, args.steps, save_every=args.save_every, sigma_position=args.sigma_position,
            sigma_attitude=args.sigma_attitude, seed=args.seed,
        )
        guess = _perturbed(truth, args.free, args.perturb, np.random.default_rng(args.seed + 1))
    else:
        obs, x0 = _load(args.data)
        guess = truth
    result = fit(obs, x0, guess, free=args.free, matrices=args.matrices, max_steps=args.max_steps, progress=not args.no_progress)
    report = {"fit": result.to_dict(), "identifiability": identifiability(result.model, x0, obs, matrices=args.matrices)}
    if args.data is None:
        param = Parametrisation(truth, args.matrices)
        labels = param.labels()
        true = dict(zip(labels, np.asarray(param.values(truth)).tolist()))
        start = dict(zip(labels, np.asarray(param.values(guess)).tolist()))
        report["truth"] = {k: true[k] for k in result.labels}
        report["guess"] = {k: start[k] for k in result.labels}
    report["settings"] = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if not callable(v)}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fit.json").write_text(json.dumps(report, indent=2))
    plot_loss(result, args.out / "loss.png")
    print(f"{'parameter':22s} {'fitted':>14s} {'± 1σ':>11s}" + (f" {'truth':>12s}" if "truth" in report else ""))
    for k, v, s in zip(result.labels, result.values, result.std):
        truth_col = f" {report['truth'][k]:12.6g}" if "truth" in report else ""
        print(f"{k:22s} {v:14.8g} {s:11.3g}{truth_col}")
    print(f"reduced χ² = {result.reduced_chi2:.3f} after {result.iterations} iterations (converged: {result.converged})")
    if not result.converged or result.reduced_chi2 > 2:
        print("warning: the fit stopped far from the noise level (reduced χ² ≫ 1): a local minimum, or wrong "
              "noise levels. Start closer (fits from ±10 % converge; from ±20 % about half do), or add stages.")
    print(f"wrote {args.out / 'fit.json'} and {args.out / 'loss.png'}")
    return result
