"""Cost of ``vi_jax.continuous.vector_field`` (the EP equations by autodiff from ℓ) against the
hand-written fields of ``benchmarks/hand_fields.py`` in the same diffrax solve.

Cases: underwater vehicle and heavy top (defaults, T = 50 s), Dopri8 and Tsit5 with diffrax's
PID controller at rtol = atol ∈ {1e-6, 1e-10}. Each solve is one jitted program taking the scene
as an argument (as ``vi-jax compare`` does) and returning the final state and step count; the
fields are timed in interleaved rounds in one process (compiled code only, median of
``--repeats``; wall time and the process's CPU time: on a loaded machine wall-time medians
carry scheduling delays, so the table also gives the ratio of the fastest runs). Two worker processes: XLA's default flags, and ``vi_jax.enable_fast_cpu_loops()``
called before any JAX work. Also timed: the hand fields written with ``@``/``jnp.cross``
(``hand_matmul``), to show which hand form is the fair peer.

    python benchmarks/vector_field.py [--repeats 7] [--tag NAME] [--report]
writes benchmarks/results/vector_field[_NAME]_{default,fast_loops}.json and prints the ratios
(``--report``: prints them from those files). ``--tag before`` holds the run on the version
before this field was sped up (git 4eea5d4's ``vi_jax/continuous.py``).
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
T = 50.0
SOLVERS = ("dopri8", "tsit5")
TOLERANCES = (1e-6, 1e-10)
FIELDS = ("vi_jax", "hand", "hand_matmul")


def measure(repeats):
    import statistics
    import time

    import diffrax
    import jax
    import numpy as np

    import vi_jax as vj

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(HERE))
    from hand_fields import heavy_top_field, vehicle_field

    scenes = {
        "vehicle": (vj.models.UnderwaterVehicle(), vehicle_field),
        "heavy_top": (vj.models.HeavyTop(), heavy_top_field),
    }
    solvers = {"dopri8": diffrax.Dopri8, "tsit5": diffrax.Tsit5}

    def program(field, solver, tol):
        def run(model, y0):
            sol = diffrax.diffeqsolve(
                field(model), solvers[solver](), 0.0, T, None, y0,
                stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol),
                saveat=diffrax.SaveAt(t1=True), max_steps=1_000_000,
            )
            return sol.ys, sol.stats["num_steps"]

        return jax.jit(run)

    rows = []
    for scene, (model, hand) in scenes.items():
        y0 = vj.continuous.initial_state(model, model.initial_state())
        fields = {
            "vi_jax": vj.continuous.vector_field,
            "hand": hand,
            "hand_matmul": lambda m, hand=hand: hand(m, elementwise=False),
        }
        for solver in SOLVERS:
            for tol in TOLERANCES:
                progs = {name: program(f, solver, tol) for name, f in fields.items()}
                outs, compile_s = {}, {}
                for name, prog in progs.items():
                    start = time.perf_counter()
                    outs[name] = jax.block_until_ready(prog(model, y0))
                    compile_s[name] = time.perf_counter() - start
                samples = {name: [] for name in progs}
                cpu = {name: [] for name in progs}
                for _ in range(repeats):  # interleaved rounds: load changes hit every field alike
                    for name, prog in progs.items():
                        start, start_cpu = time.perf_counter(), time.process_time()
                        jax.block_until_ready(prog(model, y0))
                        samples[name].append(time.perf_counter() - start)
                        cpu[name].append(time.process_time() - start_cpu)
                ref = outs["hand"][0]
                rows.append(dict(
                    scene=scene, solver=solver, rtol=tol,
                    num_steps={k: int(v[1]) for k, v in outs.items()},
                    max_state_difference={
                        k: max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                               for a, b in zip(jax.tree.leaves(v[0]), jax.tree.leaves(ref)))
                        for k, v in outs.items()
                    },
                    compile_s=compile_s,
                    median_s={k: statistics.median(v) for k, v in samples.items()},
                    median_cpu_s={k: statistics.median(v) for k, v in cpu.items()},
                    samples_s=samples,
                    samples_cpu_s=cpu,
                ))
    return dict(jax=jax.__version__, diffrax=diffrax.__version__, T=T, repeats=repeats,
                xla_flags=os.environ.get("XLA_FLAGS", ""), rows=rows)


def print_table(results):
    print("vi_jax / the faster hand field (hand, hand_matmul): medians of wall time, minima of wall time (least")
    print("disturbed run), medians of CPU time; hand@/hand: CPU medians")
    print(f"{'config':10s} {'scene':9s} {'solver':6s} {'rtol':>6s} {'steps':>6s} {'hand ms':>8s} "
          f"{'wall':>6s} {'min':>6s} {'cpu':>6s} {'hand@':>6s}")
    for config, res in results.items():
        for r in res["rows"]:
            m, c = r["median_s"], r["median_cpu_s"]
            low = {k: min(v) for k, v in r["samples_s"].items()}
            ratio = lambda d: d["vi_jax"] / min(d["hand"], d["hand_matmul"])  # noqa: E731
            print(f"{config:10s} {r['scene']:9s} {r['solver']:6s} {r['rtol']:6.0e} {r['num_steps']['hand']:6d} "
                  f"{m['hand'] * 1e3:8.3f} {ratio(m):6.2f} {ratio(low):6.2f} {ratio(c):6.2f} {c['hand_matmul'] / c['hand']:6.2f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--tag", default="")
    parser.add_argument("--report", action="store_true", help="print the table of the stored results only")
    args = parser.parse_args()
    suffix = f"_{args.tag}" if args.tag else ""
    results = {}
    for config in ("default", "fast_loops"):
        path = HERE / "results" / f"vector_field{suffix}_{config}.json"
        if args.report:
            results[config] = json.loads(path.read_text())
            continue
        env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
        cmd = [sys.executable, __file__, "--worker", config, "--repeats", str(args.repeats)]
        out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
        results[config] = json.loads(out.stdout.strip().splitlines()[-1])
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(results[config], indent=2))
        print(f"wrote {path}")
    print_table(results)

if __name__ == "__main__":
    if "--worker" in sys.argv:
        config = sys.argv[sys.argv.index("--worker") + 1]
        repeats = int(sys.argv[sys.argv.index("--repeats") + 1])
        if config == "fast_loops":
            import vi_jax

            vi_jax.enable_fast_cpu_loops()  # before any JAX computation: XLA reads its flags once
        print(json.dumps(measure(repeats)))
    else:
        main()
