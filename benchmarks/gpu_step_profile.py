"""Where a GPU spends one step of a batched ensemble: the kernels it launches per step and their
time, from a ``jax.profiler`` trace of a timed run (the GPU plane's events, grouped by kernel
name), with the member-steps per second (compiled code, median of 5). Cases: the vehicle at
order 1 through the hand-written step (``_hand_vehicle_kernel.py``, the peer), and the vehicle at
order 1, the heavy top at orders 1 and 2 (h = 0.005) through the generated step with the
accelerator plan (``_generated_step.SPECULATIVE``, ``ACCELERATOR_UNROLL``,
``PREDICT_ON_ACCELERATORS``) as it is (no suffix) or changed: ``_extrapolated`` (Newton from
2ξ_k − ξ_{k−1}), ``_one_step_per_iteration``, ``_fallback_in_step`` (the plan before the
speculative step: Newton's fallback inside every step, extrapolated), with ``_no_extrapolation``.
Also writes the vehicle's optimised HLO (``--hlo-dir``), to read the fusions behind the kernel
names. Meant for a GPU machine; runs anywhere (on a CPU the trace has no device plane and only
the rates are written).

    python benchmarks/gpu_step_profile.py [--members 1048576] [--steps 100] [--dtypes float64 float32]
        [--cases ...] [--out benchmarks/results/gpu_step_profile.json] [--hlo-dir DIR]
    python benchmarks/gpu_step_profile.py --plot [--out ...]   # the vehicle's rows as a figure, no run

``--plot`` draws µs per step of the vehicle's plans from the JSON (its latest row of each case and
dtype), split into the step's kernels, copies and time outside kernels (launch gaps and the
host's wait for the fallback check), beside the JSON as ``gpu_step_profile.png``.
"""

import argparse
import collections
import glob
import json
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _timing import time_compiled  # noqa: E402

# case → (scene, order, the accelerator plan's switches in vi_jax.engine._generated_step; None:
# the hand-written step). Default plan: SPECULATIVE, ACCELERATOR_UNROLL = 2, no extrapolation.
_PLANS = {
    "": dict(SPECULATIVE=True, ACCELERATOR_UNROLL=2, PREDICT_ON_ACCELERATORS=False),
    "_extrapolated": dict(SPECULATIVE=True, ACCELERATOR_UNROLL=2, PREDICT_ON_ACCELERATORS=True),
    "_one_step_per_iteration": dict(SPECULATIVE=True, ACCELERATOR_UNROLL=1, PREDICT_ON_ACCELERATORS=False),
    "_fallback_in_step": dict(SPECULATIVE=False, ACCELERATOR_UNROLL=1, PREDICT_ON_ACCELERATORS=True),
    "_fallback_in_step_no_extrapolation": dict(SPECULATIVE=False, ACCELERATOR_UNROLL=1, PREDICT_ON_ACCELERATORS=False),
}
CASES = {"vehicle1_hand": ("vehicle", 1, None)}
CASES.update({f"{name}{suffix}": (scene, order, plan) for name, scene, order in
              (("vehicle1", "vehicle", 1), ("heavy_top2", "heavy_top", 2), ("heavy_top1", "heavy_top", 1))
              for suffix, plan in _PLANS.items()})
STEP = {"vehicle": 0.01, "heavy_top": 0.005}


def kernels_of(trace_dir):
    """(kernel name → [launches, total µs] over the device planes' stream lines of the trace in
    ``trace_dir``, the device lines' names with their event counts)."""
    from jax.profiler import ProfileData

    (path,) = glob.glob(f"{trace_dir}/**/*.xplane.pb", recursive=True)
    data = ProfileData.from_file(path)
    out, lines = collections.defaultdict(lambda: [0, 0.0]), {}
    for plane in data.planes:
        if not plane.name.startswith("/device:"):
            continue
        for line in plane.lines:
            events = list(line.events)
            lines[f"{plane.name} {line.name}"] = len(events)
            if not line.name.lower().startswith("stream"):
                continue
            for event in events:
                out[event.name][0] += 1
                out[event.name][1] += event.duration_ns / 1e3
    return dict(out), lines


def run(case, dtype_name, members, n_steps, hlo_dir):
    import jax
    import jax.numpy as jnp

    from _hand_vehicle_kernel import hand_kernel_ensemble
    from ensemble_gpu import _scene, _states
    from vi_jax.engine import _ensemble, _generated_step

    scene, order, switches = CASES[case]
    dtype = jnp.dtype(dtype_name)
    model, x0 = _scene(scene, dtype)
    h = jnp.asarray(STEP[scene], dtype)
    states = _states(x0, members, dtype)
    for name, value in (switches or {}).items():
        setattr(_generated_step, name, value)
    jax.clear_caches()
    if switches is None:
        fn = jax.jit(lambda x: hand_kernel_ensemble(model, x, h, n_steps, save_every=n_steps, chunk=None).xi[:, -1])
    else:
        fn = jax.jit(lambda x: _ensemble.ensemble(model, x, h, n_steps, order=order, save_every=n_steps, throw=False).xi[:, -1])
    if hlo_dir and dtype_name == "float64" and case in ("vehicle1", "vehicle1_hand"):
        Path(hlo_dir).mkdir(parents=True, exist_ok=True)
        Path(hlo_dir, f"{case}_{dtype_name}.hlo.txt").write_text(fn.lower(states).compile().as_text())
    first, median, _ = time_compiled(fn, states, repeats=5)
    row = dict(case=case, dtype=dtype_name, members=members, steps=n_steps, compile_and_first_s=first,
               median_s=median, rate=members * n_steps / median, us_per_step=median / n_steps * 1e6)
    with tempfile.TemporaryDirectory() as trace_dir:
        with jax.profiler.trace(trace_dir):
            jax.block_until_ready(fn(states))
        kernels, row["trace_lines"] = kernels_of(trace_dir)
    per_step = sorted(((name, n / n_steps, us / n_steps) for name, (n, us) in kernels.items()), key=lambda k: -k[2])
    row["kernel_launches_per_step"] = sum(k[1] for k in per_step)
    row["kernel_us_per_step"] = sum(k[2] for k in per_step)
    row["kernels"] = [dict(name=name, launches_per_step=n, us_per_step=us) for name, n, us in per_step[:40]]
    print(f"{case:26s} {dtype_name}: {row['rate'] / 1e9:6.3f} G member-steps/s, {row['us_per_step']:7.1f} us/step; "
          f"{row['kernel_launches_per_step']:6.1f} kernels/step, {row['kernel_us_per_step']:7.1f} us/step in kernels", flush=True)
    for name, n, us in per_step[:12]:
        print(f"    {us:8.2f} us  {n:5.2f}x  {name}", flush=True)
    return row


PLOTTED = {"vehicle1_hand": "hand-written step (peer)", "vehicle1_fallback_in_step": "plan before: fallback inside the step",
           "vehicle1_one_step_per_iteration": "speculative, one step per loop iteration",
           "vehicle1_extrapolated": "speculative, two steps, extrapolated guess", "vehicle1": "speculative, two steps, from ξ_k (default)"}


def plot(path):
    """µs per step of the vehicle's plans (latest row of each case and dtype in the JSON)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = json.loads(Path(path).read_text())
    rows = {(r["case"], r["dtype"]): r for run in data.get("runs", [data]) for r in run["rows"]}
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.6), sharey=True)
    parts = (("kernels of the step", "tab:blue"), ("copies", "tab:red"), ("outside kernels", "tab:gray"))
    for ax, dtype in zip(axes, ("float64", "float32")):
        cases = [c for c in PLOTTED if (c, dtype) in rows]
        for y, case in enumerate(cases):
            r = rows[case, dtype]
            copies = sum(k["us_per_step"] for k in r["kernels"] if k["name"].lower().startswith("memcpy"))
            widths = (r["kernel_us_per_step"] - copies, copies, r["us_per_step"] - r["kernel_us_per_step"])
            left = 0.0
            for (label, colour), width in zip(parts, widths):
                ax.barh(y, width, left=left, color=colour, label=label if y == 0 and dtype == "float32" else None)
                left += width
            ax.text(left + 5, y, f"{r['rate'] / 1e9:.2f} G/s", va="center", fontsize=8)
        ax.set_yticks(range(len(cases)), [PLOTTED[c] for c in cases])
        ax.set_title(f"vehicle, order 1, {dtype}, 2²⁰ members")
        ax.set_xlabel("µs per step (profiler trace)")
    axes[0].invert_yaxis()  # shared: once for both
    axes[1].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    out = Path(path).with_suffix(".png")
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--members", type=int, default=1048576)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--dtypes", nargs="+", default=["float64", "float32"])
    parser.add_argument("--cases", nargs="+", default=["vehicle1_hand", "vehicle1", "vehicle1_extrapolated", "vehicle1_fallback_in_step",
                                                          "heavy_top2", "heavy_top1"], choices=list(CASES))
    parser.add_argument("--out", default=str(HERE / "results" / "gpu_step_profile.json"))
    parser.add_argument("--hlo-dir", default=None)
    parser.add_argument("--plot", action="store_true", help="draw the JSON's vehicle rows (no run)")
    args = parser.parse_args()
    if args.plot:
        return plot(args.out)
    import jax

    jax.config.update("jax_enable_x64", True)
    out = dict(command=" ".join(["python benchmarks/gpu_step_profile.py"] + sys.argv[1:]), device=str(jax.devices()[0]),
               jax=jax.__version__, rows=[])
    for dtype_name in args.dtypes:
        for case in args.cases:
            out["rows"].append(run(case, dtype_name, args.members, args.steps, args.hlo_dir))
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.out).write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
