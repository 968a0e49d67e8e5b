"""The test suite's wall time at several versions, run one after the other in this environment.

    python benchmarks/suite_time.py [--versions edec641 HEAD] [--rounds 2] [--out benchmarks/results/suite_time.json]

Each version is cloned from this repository into a temporary folder (with ``../shared`` beside
it, as CI has it) and its suite run as the README's test command runs it (``python -m pytest
-q`` with the version's own ``pyproject.toml`` options), its package first on ``PYTHONPATH``.
Every version uses this environment's packages, so only the code differs; the versions alternate
round by round, so a change of the machine's speed during the study falls on all of them (the
suite is compile-bound and this machine's speed varies by the hour: compare versions within one
study, never across studies). ``edec641`` is the version issue 11 was filed against (its
figures name ``vi_jax/_ensemble.py``, which the next commit moved). The JSON is rewritten after
every run, so a study cut short keeps the runs it finished.
"""

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path
from xml.etree import ElementTree

from _timing import machine, write_json

REPO = Path(__file__).resolve().parent.parent
COUNT = {outcome: re.compile(rf"(\d+) {outcome}") for outcome in ("passed", "failed", "error")}
SECONDS = re.compile(r" in ([\d.]+)s")


def resolve(version):
    """(full commit hash, one-line subject) of a version name."""
    log = ["git", "-C", str(REPO), "log", "-1", "--format=%H %s", version]
    sha, subject = subprocess.run(log, capture_output=True, text=True, check=True).stdout.split(" ", 1)
    return sha, subject.strip()


def checkout(sha, root):
    """A clone of the repository at ``sha`` under ``root`` (beside ``root/shared``)."""
    path = root / sha[:12]
    subprocess.run(["git", "clone", "-q", str(REPO), str(path)], check=True)
    subprocess.run(["git", "-C", str(path), "checkout", "-q", sha], check=True)
    return path


def seconds_per_test(junit):
    """Seconds of each test (setup, call and teardown) from pytest's JUnit XML report."""
    cases = ElementTree.parse(junit).getroot().iter("testcase")
    return {f"{case.get('classname')}::{case.get('name')}": round(float(case.get("time", 0.0)), 2) for case in cases}


def summary_line(stdout):
    """pytest's last line (its summary) from its output."""
    return (stdout.strip().splitlines() or [""])[-1]


def outcome_counts(summary):
    """Passed, failed and error counts in pytest's summary line."""
    return {outcome: int(found[1]) if (found := pattern.search(summary)) else 0 for outcome, pattern in COUNT.items()}


def run_suite(path):
    """Wall seconds, pytest's own summary line and its counts, and each test's seconds, for the
    suite at ``path``."""
    env = dict(os.environ, PYTHONPATH=str(path))
    junit = path / "suite_time_junit.xml"
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={junit}"],
        cwd=path, env=env, capture_output=True, text=True,
    )
    wall = time.perf_counter() - start
    last = summary_line(done.stdout)
    seconds = SECONDS.search(last)
    return {"wall_s": round(wall, 1), "pytest_s": float(seconds[1]) if seconds else None, **outcome_counts(last),
            "returncode": done.returncode, "summary": last, "tests_s": seconds_per_test(junit) if junit.exists() else {}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--versions", nargs="+", default=["edec641", "HEAD"])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "suite_time.json"))
    args = parser.parse_args()

    versions = {name: resolve(name) for name in args.versions}
    study = {
        "command": "python benchmarks/suite_time.py " + " ".join(sys.argv[1:]),
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": machine(),
        "versions": {name: {"commit": sha, "subject": subject[:200]} for name, (sha, subject) in versions.items()},
        "runs": [],
    }
    with tempfile.TemporaryDirectory(prefix="vi_jax_suite_time_") as tmp:
        root = Path(tmp)
        shared = REPO.parent / "shared"
        if shared.exists():
            (root / "shared").symlink_to(shared)
        paths = {name: checkout(sha, root) for name, (sha, _) in versions.items()}
        for round_ in range(args.rounds):
            for name, (sha, _) in versions.items():
                row = {"round": round_, "version": name, "commit": sha, **run_suite(paths[name])}
                print(f"{name} ({sha[:7]}), round {round_}: {row['summary']} (wall {row['wall_s']} s)",
                      flush=True)
                study["runs"].append(row)
                write_json(args.out, study)


if __name__ == "__main__":
    main()
