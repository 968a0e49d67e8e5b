"""Compile time and step cost of ``vj.simulate``'s first concrete calls as users get them (its
programs compiled with XLA:CPU's elemental emitters: ``vi_jax/engine/_compile_options.py``) and
with XLA's default fusion emitters forced by ``XLA_FLAGS`` (``--xla_cpu_use_fusion_emitters=true``,
which the user's flags may choose; the peer), with Newton's iterations unrolled in the
concrete call's loops (the peer of ``vi_jax.solvers._newton.rolled_iterations``), and with the
concrete call's loop and node diagnostics in one program, compiled after the whole trace (the
peer of ``vi_jax/engine/_overlapped_compiles.py``, which compiles the loop's program while the
diagnostics' program is traced and compiled).

    python benchmarks/compile_time.py        # ≈ 4 min; writes benchmarks/results/compile_time.json

Each configuration runs in its own process (XLA reads its flags once). Per scene: building the
scene and its initial state (``setup_s``, the first time in the process: eager operations compile
one small program each), the first call (trace + compile + run), XLA's backend compile time
summed over the process (JAX's monitoring events), and the median of 5 compiled runs of 20,000
steps, every node saved.
"""

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

CONFIGS = {
    "vi_jax's programs (elemental emitters)": ("", None),
    "fusion emitters (XLA's default)": ("--xla_cpu_use_fusion_emitters=true", None),
    "Newton's iterations unrolled": ("", "--unrolled"),
    "loop and node diagnostics one program": ("", "--one-program"),
}
CASES = [("UnderwaterVehicle", 1), ("UnderwaterVehicle", 2), ("HeavyTop", 2)]
N_STEPS = 20_000


def child():
    import jax

    jax.config.update("jax_enable_x64", True)
    from jax._src import monitoring

    import vi_jax as vj

    if "--unrolled" in sys.argv:  # the peer of rolled_iterations: the concrete loops' Newton unrolled
        import contextlib

        from vi_jax.engine import _advance

        _advance.rolled_iterations = contextlib.nullcontext
    if "--one-program" in sys.argv:  # the peer of run_chained: one program, compiled after its trace
        _simulate_looped_in_one_program()
    compile_s = []
    monitoring.register_event_duration_secs_listener(
        lambda event, duration, **_: compile_s.append(duration) if event.endswith("backend_compile_duration") else None
    )
    rows = []
    for scene, order in CASES:
        start = time.perf_counter()
        model = getattr(vj.models, scene)()
        x0 = jax.block_until_ready(model.initial_state())
        setup = time.perf_counter() - start
        run = lambda: jax.block_until_ready(vj.simulate(model, x0, 0.01, N_STEPS, order=order).q)  # noqa: E731
        start = time.perf_counter()
        run()
        first = time.perf_counter() - start
        samples = []
        for _ in range(5):
            start = time.perf_counter()
            run()
            samples.append(time.perf_counter() - start)
        rows.append(dict(scene=scene, order=order, setup_s=setup, first_call_s=first, us_per_step=statistics.median(samples) / N_STEPS * 1e6))
    print("JSON " + json.dumps(dict(rows=rows, backend_compile_s=sum(compile_s))))


def _simulate_looped_in_one_program():
    """``vj.simulate``'s concrete DEP call with its loop and node diagnostics in one program (as
    before ``vi_jax/engine/_overlapped_compiles.py``)."""
    from vi_jax import _validation as val
    from vi_jax._saved_nodes import first_rows, saved_capacity
    from vi_jax.engine import _simulate
    from vi_jax.engine._compile_options import single_trajectory_jit

    program = single_trajectory_jit(_simulate.loop_program)

    def looped(system, x0, h, n_saved, save_every, **options):
        every = 1 if save_every == 1 else val.step_count(save_every)
        sol = program(system, x0, h, val.step_count(n_saved), every, capacity=saved_capacity(n_saved), **options)
        return first_rows(sol, n_saved + 1)

    _simulate._simulate_looped = looped


def main():
    results = {}
    for name, (flag, peer) in CONFIGS.items():
        env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip())
        command = [sys.executable, __file__, "--child"] + ([peer] if peer else [])
        run = subprocess.run(command, env=env, capture_output=True, text=True)
        if run.returncode and "Unknown flag" in run.stderr:  # newer XLA (jax 0.11.2) dropped the option
            print(f"{name}: not available in this XLA ({flag})")
            continue
        run.check_returncode()
        results[name] = json.loads(next(line for line in run.stdout.splitlines() if line.startswith("JSON "))[5:])
        print(f"{name}: backend compile {results[name]['backend_compile_s']:.1f} s")
        for row in results[name]["rows"]:
            print(f"  {row['scene']:17s} order {row['order']}: setup {row['setup_s']:4.2f} s, first call {row['first_call_s']:5.2f} s, "
                  f"{row['us_per_step']:6.2f} us/step")
    path = Path(__file__).resolve().parent / "results" / "compile_time.json"
    path.write_text(json.dumps(dict(n_steps=N_STEPS, configs=results), indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    child() if "--child" in sys.argv else main()
