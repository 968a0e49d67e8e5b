"""The explicit splitting (``vj.simulate(scheme="splitting")``) against diffrax's solvers, error
against compiled run time (issue 12's goals), on diffrax's two vector fields: vi_jax's
``continuous.vector_field`` and the hand-written fields of ``benchmarks/hand_fields.py``.

Studies (``vi_jax.studies.work_precision``: ahead-of-time compile, one warm-up, ``--repeats``
interleaved timed rounds, medians; every program takes the model and state as arguments):

- ``short``: T = 50 s, vehicle and heavy top, splitting orders 2/4/6/8 against Tsit5, Dopri5,
  Dopri8 (PID, rtol = atol = 1e-3 … 1e-13) and fixed-step RK4; goal: fastest splitting within
  1.5× of the fastest diffrax run at every final-state accuracy 1e-3 … 1e-10;
- ``long_2e4``, ``long_2e5``: the neutrally buoyant vehicle over T = 2·10⁴ and 2·10⁵ s; goal:
  energy error ≥ 10× smaller than the best diffrax run that takes at most as long, with
  Kelvin–Noether at round-off;
- ``top_1e7``: the heavy top over 10⁷ steps of orders 2, 4 and 6 (h = 5 ms, T = 5·10⁴ s) against
  Dopri8.

Each XLA configuration runs in its own worker process: XLA's default flags, and
``vi_jax.enable_fast_cpu_loops()`` (the loop option) called before any JAX work.

    python benchmarks/splitting_vs_diffrax.py [--studies short long_2e4 long_2e5 top_1e7]
        [--configs default fast_loops] [--repeats 5] [--report]

writes benchmarks/results/splitting_vs_diffrax/{config}/{study}/work_precision.json (+ PNGs) and
prints the goal tables (``--report``: from those files only).
"""

import argparse
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "splitting_vs_diffrax"
CONFIGS = ("default", "fast_loops")


def studies():
    from vi_jax.studies import work_precision as wp

    decades = lambda lo, hi: tuple(10.0**-k for k in range(lo, hi + 1))  # noqa: E731
    splittings = tuple(("splitting", order) for order in (2, 4, 6, 8))
    common = dict(fields=("vi_jax", "hand"), repeats=5)
    short = dataclasses.replace(
        wp.FULL, systems=("vehicle", "heavy_top"), schemes=splittings, steps=wp.SPLITTING_STEPS,
        tolerances={"tsit5": decades(3, 13), "dopri5": decades(3, 13), "dopri8": decades(3, 13)},
        long_system=None, **common,
    )
    long = dict(systems=(), long_system="vehicle_neutral", rk4=False, n_save=400)
    return {
        "short": short,
        "long_2e4": dataclasses.replace(
            wp.FULL, long_T=20_000.0, long_schemes=wp.LONG_SPLITTINGS,
            long_tolerances={"tsit5": (1e-9, 1e-12), "dopri8": (1e-8, 1e-10, 1e-11, 1e-12, 1e-14)}, **long, **common,
        ),
        "long_2e5": dataclasses.replace(
            wp.FULL, long_T=200_000.0, long_schemes=(("splitting", 8, 400_000), ("splitting", 6, 800_000)),
            long_tolerances={"dopri8": (1e-10, 1e-12, 1e-14)}, **long, **common,
        ),
        "top_1e7": dataclasses.replace(
            wp.FULL, long_T=50_000.0,
            long_schemes=(("splitting", 2, 10_000_000), ("splitting", 4, 10_000_000), ("splitting", 6, 10_000_000)),
            long_tolerances={"dopri8": (1e-10, 1e-12)}, **{**long, "long_system": "heavy_top"}, **common,
        ),
    }


def register_hand_fields():
    from hand_fields import heavy_top_field, vehicle_field

    from vi_jax.models import UnderwaterVehicle
    from vi_jax.studies import _timing

    _timing.FIELDS["hand"] = lambda m: vehicle_field(m) if isinstance(m, UnderwaterVehicle) else heavy_top_field(m)


def worker(config, names, repeats):
    if config == "fast_loops":
        import vi_jax

        vi_jax.enable_fast_cpu_loops()
    import jax

    jax.config.update("jax_enable_x64", True)
    from vi_jax.studies.work_precision import run_study

    sys.path.insert(0, str(HERE))
    register_hand_fields()
    for name in names:
        study = dataclasses.replace(studies()[name], repeats=repeats)
        out = RESULTS / config / name
        run_study(study, out, progress=False, command=f"benchmarks/splitting_vs_diffrax.py ({config})")
        print(f"wrote {out / 'work_precision.json'}", flush=True)


def report():
    """The goal tables of the stored results (goals recomputed from the stored measurements)."""
    from vi_jax.studies.work_precision import _long_horizon_goal, _work_precision_goal, format_tables

    for config in CONFIGS:
        for path in sorted((RESULTS / config).glob("*/work_precision.json")):
            result = json.loads(path.read_text())
            for data in result["work_precision"].values():
                data["goal"] = _work_precision_goal(data["peers"])
            if result["long_horizon"]:
                result["long_horizon"]["goal"] = _long_horizon_goal(result["long_horizon"]["peers"])
            path.write_text(json.dumps(result, indent=1))
            print(f"\n===== {config} / {path.parent.name} ({result['meta']['wall_s']:.0f} s)")
            print("\n".join(line for line in format_tables(result).splitlines() if not line.startswith(("vi_jax ", "diffrax "))))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", nargs="+", default=["short", "long_2e4", "long_2e5", "top_1e7"])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=CONFIGS)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--report", action="store_true")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker(args.worker, args.studies, args.repeats)
    if not args.report:
        for config in args.configs:
            cmd = [sys.executable, __file__, "--worker", config, "--repeats", str(args.repeats), "--studies", *args.studies]
            subprocess.run(cmd, env={**os.environ, "PYTHONPATH": str(HERE)}, check=True)
    report()


if __name__ == "__main__":
    main()
