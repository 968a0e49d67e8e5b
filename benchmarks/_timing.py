"""Timing helpers shared by the benchmarks: compiled code only (warm-up, block_until_ready,
median of repeats), compile time reported separately."""

import contextlib
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import jax


@contextlib.contextmanager
def under_patches(patches):
    """Every one of ``patches`` (``mock.patch`` objects) active."""
    with contextlib.ExitStack() as stack:
        for patch in patches:
            stack.enter_context(patch)
        yield


def compiled_under(fn, *args, patches=()):
    """``fn`` jitted and compiled for ``args`` under ``patches`` (the trace sees them; the
    compiled program keeps them): (compile + first run seconds, a call, its output)."""
    start = time.perf_counter()
    with under_patches(patches):
        compiled = jax.jit(fn).lower(*args).compile()
    out = jax.block_until_ready(compiled(*args))
    return time.perf_counter() - start, lambda: compiled(*args), out


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


def alternate_samples(calls, repeats=7):
    """Seconds of each of ``calls`` (name → a call returning arrays), a list per name, timed one
    after another ``repeats`` times: peers in one process share the machine's load."""
    samples = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            jax.block_until_ready(call())
            samples[name].append(time.perf_counter() - start)
    return samples


def time_alternately(calls, repeats=7):
    """Median seconds of each of ``calls``, timed as :func:`alternate_samples` does."""
    return {name: statistics.median(s) for name, s in alternate_samples(calls, repeats).items()}


def cpu_per_wall(call, repeats=3):
    """CPU seconds of this process per wall second over ``repeats`` runs of ``call`` (compiled
    already): above 1, XLA ran work on more than one thread."""
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(repeats):
        jax.block_until_ready(call())
    return (time.process_time() - cpu) / (time.perf_counter() - wall)


def machine(**versions):
    """The machine and versions a study ran on (``versions``: further packages' versions)."""
    return {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(), "jax": jax.__version__, **versions}


def write_json(path, payload):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(payload, indent=2))
    print(f"wrote {path}")


def parse_args_with_fast_loops(parser=None):
    """Parse the command line with ``parser`` (a bare one if None) and a ``--fast-loops`` flag;
    with the flag, call ``vi_jax.enable_fast_cpu_loops()`` before any JAX work. Returns the
    parsed arguments (``.fast_loops``: whether the loop option is on)."""
    import argparse

    import vi_jax

    parser = argparse.ArgumentParser() if parser is None else parser
    parser.add_argument("--fast-loops", action="store_true", help="vi_jax.enable_fast_cpu_loops() first")
    args = parser.parse_args()
    if args.fast_loops:
        args.fast_loops = vi_jax.enable_fast_cpu_loops()
    return args


def fast_loops_from_argv():
    """``--fast-loops`` as the only option: see :func:`parse_args_with_fast_loops`."""
    return parse_args_with_fast_loops().fast_loops


def write_config_json(name, fast_loops, path=None, **payload):
    """``benchmarks/results/<name>[_fast_loops].json`` (or ``path``) with the XLA configuration named."""
    suffix = "_fast_loops" if fast_loops else ""
    config = "enable_fast_cpu_loops()" if fast_loops else "default XLA flags"
    path = path or Path(__file__).resolve().parent / "results" / f"{name}{suffix}.json"
    write_json(path, dict(config=config, **payload))


def fresh_process_runs(child, cases, repeats):
    """``child`` (a Python script printing ``JSON {...}``) run in a fresh process per case and
    repeat, the cases in turn; ``cases``: {key: its command-line arguments}. Returns {key: the
    JSON dicts of its runs}."""
    runs = {key: [] for key in cases}
    for _ in range(repeats):
        for key, args in cases.items():
            out = subprocess.run([sys.executable, "-c", child, *map(str, args)], capture_output=True, text=True, check=True).stdout
            runs[key].append(json.loads(out.split("JSON ", 1)[1]))
    return runs


def medians(runs, keys):
    """{key: the median of the runs' values}."""
    return {key: statistics.median(r[key] for r in runs) for key in keys}
