"""Timing helpers shared by the benchmarks: compiled code only (warm-up, block_until_ready,
median of repeats), compile time reported separately."""

import json
import statistics
import time
from pathlib import Path

import jax


def time_compiled(fn, *args, repeats=7):
    """(compile + first run seconds, median seconds of ``repeats`` further runs, last output)."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        samples.append(time.perf_counter() - start)
    return first, statistics.median(samples), out


def write_json(path, payload):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(payload, indent=2))
    print(f"wrote {path}")
