"""The ``vi-jax`` command line.

  vi-jax simulate underwater --tau cayley --h 0.01 --steps 50000 --out DIR
  vi-jax simulate beam [--scenario free|clamped|paper] --out DIR
  vi-jax compare [--quick] --out DIR
  vi-jax fit [--data FILE.npz] --out DIR

``simulate underwater`` writes ``DIR/trajectory.npz`` (t, R, q, omega, nu, energy,
kelvin_noether; leading axis = time) and PNG plots. Bad input is reported in one line with a
non-zero exit status. The command line compiles small-step loops into single XLA:CPU kernels
(``vi_jax/_cpu_tuning.py``) unless ``XLA_FLAGS`` already sets ``xla_backend_extra_options``.
"""

import argparse
import sys
from pathlib import Path


def _add_underwater_arguments(sim):
    sim.add_argument("--tau", default="cayley", choices=["cayley", "exp"], help="group difference map")
    sim.add_argument("--order", type=int, default=1, choices=[1, 2, 4, 6], help="1 = the paper's rule (eq. 71)")
    sim.add_argument("--h", type=float, default=0.01, help="time step [s]")
    sim.add_argument("--steps", type=int, default=50_000, help="number of steps")
    sim.add_argument("--save-every", type=int, default=1, help="save every k-th node")
    sim.add_argument("--float32", action="store_true", help="run in float32 (default float64)")
    sim.add_argument("--out", type=Path, default=Path("out/underwater"), help="output directory")
    sim.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _parser():
    from ._compare import add_compare_arguments, run_compare
    from ._fit_cli import add_fit_arguments, run_fit
    from .multisymplectic._cli import add_beam_arguments, run_beam

    parser = argparse.ArgumentParser(prog="vi-jax", description="Lie-group variational integrators in JAX")
    commands = parser.add_subparsers(dest="command", required=True)
    simulate = commands.add_parser("simulate", help="integrate a shipped model and write data and plots")
    models = simulate.add_subparsers(dest="model", required=True)
    underwater = models.add_parser("underwater", help="the underwater vehicle of seed 000 (the paper's run by default)")
    _add_underwater_arguments(underwater)
    underwater.set_defaults(run=_simulate_underwater)
    beam = models.add_parser("beam", help="the geometrically exact beam of seed 003")
    add_beam_arguments(beam)
    beam.set_defaults(run=run_beam)
    compare = commands.add_parser("compare", help="error against run time: vi_jax schemes and diffrax solvers")
    add_compare_arguments(compare)
    compare.set_defaults(run=run_compare)
    fit = commands.add_parser("fit", help="recover the underwater vehicle's parameters from observed motion")
    add_fit_arguments(fit)
    fit.set_defaults(run=run_fit)
    return parser


def _simulate_underwater(args):
    import jax

    jax.config.update("jax_enable_x64", not args.float32)
    import numpy as np

    import vi_jax as vj
    from vi_jax.plots import plot_vehicle_run

    model = vj.models.UnderwaterVehicle()
    sol = vj.simulate(
        model, model.initial_state(), args.h, args.steps, tau=args.tau, order=args.order,
        save_every=args.save_every, progress=not args.no_progress,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez(
        args.out / "trajectory.npz",
        t=sol.t, R=sol.R, q=sol.q, omega=sol.omega, nu=sol.nu,
        energy=sol.energy, kelvin_noether=sol.kelvin_noether,
    )
    label = f"{args.tau}, order {args.order}, h = {args.h:g}"
    paths = plot_vehicle_run({label: sol}, args.out)
    energy = np.asarray(sol.energy)
    kn = np.asarray(sol.kelvin_noether)
    print(f"q(T) = {np.asarray(sol.q[-1])}")
    print(f"max |ΔE/E₀| = {np.max(np.abs(energy / energy[0] - 1)):.3e}")
    print(f"max |ΔI/I₀| = {np.max(np.abs(kn / kn[0] - 1)):.3e}")
    print(f"wrote {args.out / 'trajectory.npz'} and " + ", ".join(p.name for p in paths))


def main(argv=None):
    from ._cpu_tuning import enable_fast_cpu_loops

    enable_fast_cpu_loops()  # before the first JAX computation of this process
    args = _parser().parse_args(argv)
    try:
        args.run(args)
    except ValueError as err:
        print(f"vi-jax: error: {err}", file=sys.stderr)
        return 2
    except RuntimeError as err:  # NewtonFailure and equinox runtime errors
        print(f"vi-jax: error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
