"""Where the test suite's time goes, by XLA backend optimisation level: wall seconds, and the
seconds JAX reports for tracing, lowering to MLIR and backend compilation, summed over the tests
of every xdist worker (its monitoring events, by ``_suite_profile_plugin.py``).

    python benchmarks/suite_profile.py [--levels 0 3] [--rounds 1] [--out benchmarks/results/suite_profile.json]

Each run is this checkout's suite as the README's test command runs it (``python -m pytest -q``),
with ``XLA_FLAGS=--xla_backend_optimization_level=N`` (``tests/conftest.py`` then leaves the level
as named; 0 is what it picks by itself, 3 XLA's default). Levels alternate round by round, so a
change of the machine's speed falls on each. Backend compile includes reading the suite's
persistent compilation cache on a hit (``cache_retrieval_time_sec`` gives that part).
"""

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from _timing import machine, write_json
from suite_time import outcome_counts, summary_line

REPO = Path(__file__).resolve().parent.parent
PHASES = ("jaxpr_trace_duration", "jaxpr_to_mlir_module_duration", "backend_compile_duration",
          "cache_retrieval_time_sec", "wall")


def run_suite(level):
    """Wall seconds, pytest's summary, and the phase sums (all tests, and the ten tests that spend
    most in backend compilation) of one run at LLVM level ``level``."""
    with tempfile.TemporaryDirectory(prefix="vi_jax_suite_profile_") as folder:
        flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_backend_optimization_level={level}".strip()
        env = dict(os.environ, XLA_FLAGS=flags, VI_JAX_SUITE_PROFILE_DIR=folder,
                   PYTHONPATH=os.pathsep.join([str(REPO / "benchmarks"), os.environ.get("PYTHONPATH", "")]))
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               "-p", "_suite_profile_plugin"], cwd=REPO, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
        tests = {}
        for worker in Path(folder).glob("*.json"):
            tests.update(json.loads(worker.read_text()))
    last = summary_line(done.stdout)
    totals = collections.Counter()
    for phases in tests.values():
        totals.update(phases)
    heaviest = sorted(tests, key=lambda test: -tests[test].get("backend_compile_duration", 0.0))[:10]
    return {"level": level, "wall_s": round(wall, 1), "summary": last, "returncode": done.returncode,
            **outcome_counts(last),
            "worker_s": {phase: round(totals[phase], 1) for phase in PHASES},
            "compiles": int(totals["count_backend_compile_duration"]),
            "cache_hits": int(totals["count_cache_hits"]),
            "heaviest_backend_compile_s": {test: round(tests[test].get("backend_compile_duration", 0.0), 1)
                                           for test in heaviest}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", nargs="+", type=int, default=[0, 3])
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "suite_profile.json"))
    args = parser.parse_args()

    head = subprocess.run(["git", "-C", str(REPO), "log", "-1", "--format=%H"], capture_output=True, text=True)
    study = {"command": "python benchmarks/suite_profile.py " + " ".join(sys.argv[1:]),
             "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "commit": head.stdout.strip(),
             "machine": machine(),
             "runs": []}
    for round_ in range(args.rounds):
        for level in args.levels:
            row = {"round": round_, **run_suite(level)}
            print(f"level {level}, round {round_}: {row['summary']} (wall {row['wall_s']} s); worker seconds "
                  + ", ".join(f"{phase} {seconds}" for phase, seconds in row["worker_s"].items()), flush=True)
            study["runs"].append(row)
            write_json(args.out, study)


if __name__ == "__main__":
    main()
