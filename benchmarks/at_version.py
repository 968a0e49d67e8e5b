"""One of this checkout's benchmarks run against another version's ``vi_jax``: the same
benchmark code, the package of ``VERSION`` (a clone of this repository at that commit, first on
the import path), in this environment. For version-to-version comparisons, run in alternation
with the benchmark on this checkout:

    python benchmarks/at_version.py VERSION benchmarks/SCRIPT.py [its options]

It says which package it loaded and stops if that is not the clone's. Mind the script's
``--out``: by default it writes this checkout's ``benchmarks/results/``.
"""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from suite_time import checkout, resolve


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    version, script, *options = sys.argv[1:]
    sha, subject = resolve(version)
    with tempfile.TemporaryDirectory(prefix="vi_jax_at_version_") as root:
        path = checkout(sha, Path(root))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(path), os.environ.get("PYTHONPATH")])))
        where = [sys.executable, "-c", "import vi_jax; print(vi_jax.__file__)"]
        loaded = subprocess.run(where, env=env, cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        if not Path(loaded).is_relative_to(path):
            sys.exit(f"vi_jax loaded from {loaded}, not from the clone of {sha[:12]} at {path}")
        print(f"{sha[:12]} ({subject[:80]}): vi_jax from {loaded}", flush=True)
        sys.exit(subprocess.run([sys.executable, script, *options], env=env).returncode)


if __name__ == "__main__":
    main()
