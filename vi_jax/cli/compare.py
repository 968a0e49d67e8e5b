"""``vi-jax compare``: error against run time, vi_jax schemes and diffrax solvers
(``vi_jax.studies.work_precision``)."""

import dataclasses
from pathlib import Path

import jax

from ..studies.work_precision import FULL, QUICK, format_tables, run_study


def add_compare_arguments(parser):
    """The options of ``vi-jax compare`` (and ``benchmarks/work_precision.py``)."""
    parser.add_argument("--quick", action="store_true", help="small sizes (about 1–2 min) instead of the full study")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per configuration (median reported; ≥ 5)")
    parser.add_argument("--out", type=Path, default=Path("out/compare"), help="directory for work_precision.json and PNGs")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return parser


def run_compare(args):
    """Run the study chosen by ``args`` (see :func:`add_compare_arguments`), print the tables."""
    import sys

    jax.config.update("jax_enable_x64", True)
    if args.repeats < 5:
        raise ValueError(f"--repeats: expected at least 5 (median of ≥ 5 timed runs), got {args.repeats}")
    study = dataclasses.replace(QUICK if args.quick else FULL, repeats=args.repeats)
    result = run_study(study, args.out, progress=not args.no_progress, command=" ".join(sys.argv))
    print(format_tables(result))
    print(f"\nwrote {args.out / 'work_precision.json'} and work_precision.png, long_horizon.png, energy_vs_time.png "
          f"({result['meta']['wall_s']:.0f} s)")
    return result
