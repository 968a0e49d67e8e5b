"""``vi-jax fit``: recover the underwater vehicle's parameters from telemetry, writing
``DIR/fit.json`` (fitted values, σ, correlations, the initial state, residuals per channel, what
the channels given identify and which extra channel would identify the rest) and the figures
``DIR/loss.png`` (loss per iteration), ``DIR/channels.png`` (fitted against observed, per
channel) and ``DIR/residuals.png`` (whitened residuals against time).

``--data FILE.csv`` reads telemetry (format: ``vi_jax/fitting/_csv.py``; an example is
``docs/telemetry_example.csv``) with the noise levels ``--sigma-*``; ``--data FILE.npz`` grid
observations (arrays ``q`` (n+1, 3), ``R`` (n+1, 3, 3), ``omega0``, ``v0`` and scalars ``h``,
``save_every``, ``sigma_position``, ``sigma_attitude``). Both start from the Table 1 vehicle and
estimate the initial state with the parameters. Without ``--data`` the observations are
synthesized from the Table 1 vehicle (with noise) and the fit starts from a guess whose free
parameters are off by the log-scale error ``--perturb`` (signs at random, seeded by ``--seed``).
"""

import json
from pathlib import Path

import numpy as np

from ..fitting._fit import CONTINUITY, DEFAULT_FREE
from ..fitting._parametrisation import MATRICES, OFFSET_SCALE, PARAMETERS
from ..fitting._robust import LOSSES
from ..plots.fit import plot_channels, plot_loss, plot_residuals


def add_fit_arguments(parser):
    """Add the ``vi-jax fit`` options to an argparse (sub)parser."""
    parser.add_argument("--data", type=Path, default=None, help="telemetry (.csv) or grid observations (.npz); default: synthesize them")
    parser.add_argument("--h", type=float, default=0.05, help="time step of the model [s]")
    parser.add_argument("--steps", type=int, default=400, help="number of steps (synthetic data)")
    parser.add_argument("--save-every", type=int, default=10, help="steps between samples (synthetic data)")
    parser.add_argument("--sigma-position", type=float, default=0.01, help="position noise [m]")
    parser.add_argument("--sigma-attitude", type=float, default=0.01, help="attitude noise [rad]")
    parser.add_argument("--sigma-rates", type=float, default=0.01, help="body-rate noise [rad/s] (CSV p, q, r)")
    parser.add_argument("--sigma-velocity", type=float, default=0.01, help="body-velocity noise [m/s] (CSV u, v, w)")
    parser.add_argument("--seed", type=int, default=0, help="noise and guess seed (synthetic data)")
    parser.add_argument("--perturb", type=float, default=0.1, help="log-scale error of the initial guess (synthetic data)")
    parser.add_argument("--free", nargs="+", default=list(DEFAULT_FREE), choices=PARAMETERS, help="parameters to fit")
    parser.add_argument("--matrices", default="diagonal", choices=MATRICES, help="diagonal or full SPD matrices")
    parser.add_argument("--loss", default="squared", choices=LOSSES, help="robust losses down-weight outliers")
    parser.add_argument("--segments", type=int, default=None, help="multiple-shooting segments (default: one per sample interval, at most 64; 1: single shooting)")
    parser.add_argument("--max-steps", type=int, default=100, help="iterations per stage")
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


def _load_npz(path):
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


def _load(args):
    """(data, x0 guess or None, h) from ``--data``."""
    from ..fitting._csv import read_telemetry

    if not args.data.is_file():
        raise ValueError(f"data: no such file {str(args.data)!r}")
    if args.data.suffix == ".npz":
        obs, x0 = _load_npz(args.data)
        return obs, x0, obs.h
    if args.data.suffix != ".csv":
        raise ValueError(f"data: expected a .csv or .npz file, got {str(args.data)!r}")
    sigma = {"position": args.sigma_position, "attitude": args.sigma_attitude, "rates": args.sigma_rates, "velocity": args.sigma_velocity}
    return read_telemetry(args.data, sigma=sigma), None, args.h


def run_fit(args):
    """Run ``vi-jax fit`` with parsed ``args``; raises ValueError on bad input."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from ..fitting import Parametrisation, fit, synthesize
    from ..fitting._fit import as_telemetry
    from ..models import UnderwaterVehicle

    truth = UnderwaterVehicle()
    if args.data is None:
        data = synthesize(
            truth, truth.initial_state(), args.h, args.steps, save_every=args.save_every, sigma_position=args.sigma_position,
            sigma_attitude=args.sigma_attitude, seed=args.seed,
        )
        x0, h = None, args.h
        guess = _perturbed(truth, args.free, args.perturb, np.random.default_rng(args.seed + 1))
    else:
        data, x0, h = _load(args)
        guess = truth
    result = fit(
        data, x0, guess, h=h, free=args.free, matrices=args.matrices, loss=args.loss, segments=args.segments,
        max_steps=args.max_steps, progress=not args.no_progress,
    )
    report = {"fit": result.to_dict()}
    if args.data is None:
        param = Parametrisation(truth, args.matrices)
        labels = param.labels()
        true = dict(zip(labels, np.asarray(param.values(truth)).tolist()))
        start = dict(zip(labels, np.asarray(param.values(guess)).tolist()))
        report["truth"] = {k: true[k] for k in result.labels}
        report["guess"] = {k: start[k] for k in result.labels}
    report["settings"] = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if not callable(v)}
    report["settings"]["continuity"] = list(CONTINUITY)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fit.json").write_text(json.dumps(report, indent=2))
    telemetry = as_telemetry(data)
    plot_loss(result, args.out / "loss.png")
    plot_channels(result, telemetry, args.out / "channels.png")
    plot_residuals(result, telemetry, args.out / "residuals.png")
    _print_summary(result, report)
    print(f"wrote {args.out / 'fit.json'}, loss.png, channels.png and residuals.png")
    return result


def _print_summary(result, report):
    truth = report.get("truth")
    print(f"{'parameter':22s} {'fitted':>14s} {'± 1σ':>11s}" + (f" {'truth':>12s}" if truth else ""))
    for k, v, s in zip(result.labels, result.values, result.std):
        print(f"{k:22s} {v:14.8g} {s:11.3g}" + (f" {truth[k]:12.6g}" if truth else ""))
    for c, row in result.channels.items():
        print(f"{c:9s}: {row['observed_components']} components observed, RMS whitened residual {row['rms_whitened']:.3f}")
    ident = result.identifiability
    if ident["not_identifiable"]:
        print(f"not identifiable from these channels: {', '.join(ident['not_identifiable'])}")
        for c, row in ident["adding_a_channel"].items():
            if row["identifies"]:
                print(f"  adding {c} would identify: {', '.join(row['identifies'])}")
    print(f"reduced χ² = {result.reduced_chi2:.3f} after {result.iterations} iterations (converged: {result.converged})")
    if not result.converged or result.reduced_chi2 > 2:
        print("warning: the fit stopped far from the noise level (reduced χ² ≫ 1) or did not converge: wrong noise "
              "levels, outliers (try --loss huber), or a start too far away (try more --segments or --max-steps).")
