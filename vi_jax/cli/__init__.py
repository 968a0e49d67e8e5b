"""The ``vi-jax`` command line (one module per subcommand: simulate, beam, compare, fit).

  vi-jax simulate underwater --tau cayley --h 0.01 --steps 50000 --out DIR
  vi-jax simulate beam [--scenario free|clamped|paper] --out DIR
  vi-jax compare [--quick] --out DIR
  vi-jax fit [--data FILE.csv|FILE.npz] --out DIR

``simulate underwater`` writes ``DIR/trajectory.npz`` (t, R, q, omega, nu, energy,
kelvin_noether; leading axis = time) and PNG plots. Bad input is reported in one line with a
non-zero exit status (2); a failed step exits 1; a run whose energy error says it is
meaningless (``vi_jax.AccuracyWarning``) writes its files, says so on stderr and exits 3.
The command line compiles small-step loops into single XLA:CPU kernels
(``vi_jax/engine/_cpu_tuning.py``) unless ``XLA_FLAGS`` already sets ``xla_backend_extra_options``,
and under an unlimited stack limit asks OpenBLAS for one thread unless a count is set
(``vi_jax/_openblas_threads.py``).
"""

import argparse
import sys
import warnings

MEANINGLESS_EXIT = 3  # the run finished, but its energy error says the result is meaningless


def _parser():
    from .compare import add_compare_arguments, run_compare
    from .fit import add_fit_arguments, run_fit
    from .beam import add_beam_arguments, run_beam
    from .simulate import add_underwater_arguments, run_underwater

    parser = argparse.ArgumentParser(prog="vi-jax", description="Lie-group variational integrators in JAX")
    commands = parser.add_subparsers(dest="command", required=True)
    simulate = commands.add_parser("simulate", help="integrate a shipped model and write data and plots")
    models = simulate.add_subparsers(dest="model", required=True)
    underwater = models.add_parser("underwater", help="the underwater vehicle of seed 000 (the paper's run by default)")
    add_underwater_arguments(underwater)
    underwater.set_defaults(run=run_underwater)
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


def main(argv=None):
    from .._openblas_threads import one_openblas_thread_if_stacks_are_small
    from ..engine._cpu_tuning import backend_started, enable_fast_cpu_loops

    if not backend_started():  # the command's own process (called in a running session: its flags stay)
        enable_fast_cpu_loops()
        one_openblas_thread_if_stacks_are_small()
    from .._accuracy import AccuracyWarning

    args = _parser().parse_args(argv)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", AccuracyWarning)
            args.run(args)
    except ValueError as err:
        print(f"vi-jax: error: {err}", file=sys.stderr)
        return 2
    except RuntimeError as err:  # NewtonFailure and equinox runtime errors
        print(f"vi-jax: error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 1
    meaningless = [w for w in caught if issubclass(w.category, AccuracyWarning)]
    for w in meaningless:
        print(f"vi-jax: warning: {w.message} The files were written for inspection.", file=sys.stderr)
    return MEANINGLESS_EXIT if meaningless else 0


if __name__ == "__main__":
    sys.exit(main())
