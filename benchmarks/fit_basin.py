"""Basin of attraction of ``vj.fit``: from many random first guesses (every free parameter off
by a log-scale error ``--perturb``, signs at random, as ``vi-jax fit --perturb P --seed S``),
how many fits reach the truth within 4σ (every σ finite and every |fitted − true| ≤ 4σ, σ from
the fit's Fisher information), with their iterations and times. Synthetic data as ``vi-jax fit``'s defaults
(noise seeded by S).

    python benchmarks/fit_basin.py --seeds 0-49 --perturb 0.4 [--segments N] [--workers 2]
"""

import argparse
import json
import multiprocessing
import time
from pathlib import Path


def one(args):
    seed, perturb, segments, continuity = args
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from vi_jax.cli.fit import _perturbed
    from vi_jax.fitting import Parametrisation, fit, synthesize
    from vi_jax.fitting._fit import DEFAULT_FREE
    from vi_jax.models import UnderwaterVehicle

    truth = UnderwaterVehicle()
    x0 = truth.initial_state()
    obs = synthesize(truth, x0, 0.05, 400, save_every=10, sigma_position=0.01, sigma_attitude=0.01, seed=seed)
    guess = _perturbed(truth, DEFAULT_FREE, perturb, np.random.default_rng(seed + 1))
    start = time.perf_counter()
    try:
        result = fit(obs, None, guess, segments=segments, **({} if continuity is None else {"continuity": continuity}))
    except Exception as err:  # a failed fit is a data point, not a crash of the study
        return {"seed": seed, "error": f"{type(err).__name__}: {err}", "seconds": time.perf_counter() - start}
    param = Parametrisation(truth)
    true = np.asarray(param.values(truth))[param.indices(DEFAULT_FREE)]
    z = (result.values - true) / result.std
    return {
        "seed": seed,
        "max_abs_z": float(np.max(np.abs(z))) if np.all(np.isfinite(result.std)) else None,
        "reduced_chi2": result.reduced_chi2,
        "iterations": result.iterations,
        "converged": result.converged,
        "seconds": time.perf_counter() - start,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0-49", help="range A-B (inclusive) or a list A,B,C")
    parser.add_argument("--perturb", type=float, default=0.4)
    parser.add_argument("--segments", type=int, default=None, help="multiple-shooting segments (default: vj.fit's)")
    parser.add_argument("--continuity", type=float, nargs="+", default=None, help="continuity weights (default: vj.fit's)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/fit_basin.json"))
    args = parser.parse_args()
    seeds = [int(x) for x in args.seeds.split(",")] if "," in args.seeds else range(*(lambda a, b: (a, b + 1))(*map(int, args.seeds.split("-"))))
    jobs = [(s, args.perturb, args.segments, args.continuity) for s in seeds]
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        rows = []
        for row in pool.imap(one, jobs):
            rows.append(row)
            print(json.dumps(row), flush=True)
    ok = [r for r in rows if r.get("max_abs_z") is not None and r["max_abs_z"] <= 4.0]
    summary = {
        "perturb": args.perturb,
        "segments": args.segments,
        "continuity": args.continuity,
        "starts": len(rows),
        "within_4_sigma": len(ok),
        "fraction": len(ok) / len(rows),
        "median_seconds": float(np.median([r["seconds"] for r in rows])),
        "rows": rows,
    }
    print(f"{len(ok)}/{len(rows)} fits within 4σ of the truth (perturb {args.perturb}); median {summary['median_seconds']:.1f} s per fit")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    import numpy as np

    main()
