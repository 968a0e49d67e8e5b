"""Wall time of one ``vj.fit`` of the 9 default free parameters (and the initial state) to 200
irregularly spaced samples of positions and attitudes over 60 s (σ = 1 cm, 0.01 rad), from a
guess 20–30 % off, compile included: what a user waits for. ``--fast-loops``: with
``vj.enable_fast_cpu_loops()`` (as the ``vi-jax`` command line runs), else default XLA flags.

    python benchmarks/fit_time.py [--repeats 3] [--segments N] [--fast-loops]
"""

import argparse
import statistics
import time

import jax
import numpy as np

from _timing import parse_args_with_fast_loops, write_config_json


def fit_problem():
    """(truth, sample times, telemetry, first guess) of the timed fit (also
    ``benchmarks/emitters.py``'s fit rows)."""
    import vi_jax as vj

    truth = vj.models.UnderwaterVehicle()
    t = np.concatenate([[0.0], np.sort(np.random.default_rng(0).uniform(0.0, 60.0, 199))])
    data = vj.synthesize_telemetry(truth, truth.initial_state(), t, sigma={"position": 0.01, "attitude": 0.01}, h=0.05, order=1, seed=2)
    guess = vj.models.UnderwaterVehicle(added_mass=(80.0, 55.0, 90.0), inertia=(4.5, 6.5, 5.0), buoyancy_offset=(0.003, -0.004, -0.012))
    return truth, t, data, guess


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="fits, each in this process (the first compiles)")
    parser.add_argument("--segments", type=int, default=None)
    args = parse_args_with_fast_loops(parser)
    jax.config.update("jax_enable_x64", True)
    import vi_jax as vj
    from vi_jax.fitting import Parametrisation
    from vi_jax.fitting._fit import DEFAULT_FREE

    truth, t, data, guess = fit_problem()
    param = Parametrisation(truth)
    true = np.asarray(param.values(truth))[param.indices(DEFAULT_FREE)]
    rows = []
    for k in range(args.repeats):
        start = time.perf_counter()
        result = vj.fit(data, None, guess, h=0.05, segments=args.segments)
        seconds = time.perf_counter() - start
        z = (result.values - true) / result.std
        rows.append({"seconds": seconds, "iterations": result.iterations, "max_abs_z": float(np.max(np.abs(z))), "reduced_chi2": result.reduced_chi2})
        print(f"fit {k + 1}: {seconds:.1f} s, {result.iterations} iterations, max |z| = {rows[-1]['max_abs_z']:.2f}, reduced χ² = {result.reduced_chi2:.3f}")
    write_config_json("fit_time", args.fast_loops, **{"samples": int(t.size), "parameters": len(true), "segments": args.segments, "first_seconds": rows[0]["seconds"],
                          "median_seconds": statistics.median(r["seconds"] for r in rows), "rows": rows})


if __name__ == "__main__":
    main()
