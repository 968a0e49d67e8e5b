"""How often a 777 × 777 ``jnp.linalg.solve`` (the fit's Gauss–Newton system: 9 parameters and
12 unknowns per segment, 64 segments) crashes, by stack limit and OpenBLAS thread count: fresh
processes, each solving 200 times (``vi_jax/_openblas_threads.py`` says why).

    python benchmarks/openblas_threads.py [--runs 10] [--out benchmarks/results/openblas_threads.json]

Configurations, run alternately: the stack limit unlimited with OpenBLAS's default threads, the
same with ``OPENBLAS_NUM_THREADS=1``, and an 8 MB limit with the default threads. Needs a hard
stack limit of unlimited (else the first two are skipped) and Linux.
"""

import argparse
import os
import resource
import signal
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

from _timing import machine, write_json

from vi_jax._openblas_threads import THREAD_VARIABLES

REPO = Path(__file__).resolve().parent.parent
SOLVES = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
n = 777
A = jnp.asarray(np.random.default_rng(0).normal(size=(n, n))) + n * jnp.eye(n)
solve = jax.jit(jnp.linalg.solve)
for _ in range(200):
    solve(A, jnp.ones(n)).block_until_ready()
"""
CONFIGS = {
    "unlimited stack, default threads": (resource.RLIM_INFINITY, {}),
    "unlimited stack, OPENBLAS_NUM_THREADS=1": (resource.RLIM_INFINITY, {"OPENBLAS_NUM_THREADS": "1"}),
    "8 MB stack, default threads": (8 * 2**20, {}),
}


def run(stack, env):
    """The child's return code (−11: a segmentation fault)."""
    def limits():
        resource.setrlimit(resource.RLIMIT_STACK, (stack, resource.getrlimit(resource.RLIMIT_STACK)[1]))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))

    base = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    return subprocess.run([sys.executable, "-c", SOLVES], env={**base, **env}, preexec_fn=limits,
                          capture_output=True).returncode


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "openblas_threads.json"))
    args = parser.parse_args()
    hard = resource.getrlimit(resource.RLIMIT_STACK)[1]
    configs = {name: c for name, c in CONFIGS.items() if hard == resource.RLIM_INFINITY or c[0] != resource.RLIM_INFINITY}
    codes = {name: [] for name in configs}
    for _ in range(args.runs):
        for name, (stack, env) in configs.items():
            codes[name].append(run(stack, env))
    import scipy

    study = {"command": "python benchmarks/openblas_threads.py " + " ".join(sys.argv[1:]),
             "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
             "machine": machine(scipy=scipy.__version__),
             "configs": {name: {"runs": len(c), "segfaults": c.count(-signal.SIGSEGV),
                                "other_failures": sum(1 for x in c if x not in (0, -signal.SIGSEGV)), "return_codes": c}
                         for name, c in codes.items()}}
    for name, row in study["configs"].items():
        print(f"{name}: {row['segfaults']} of {row['runs']} runs crashed (segfault), {row['other_failures']} failed otherwise")
    write_json(args.out, study)


if __name__ == "__main__":
    main()
