"""Checkpointed reverse mode: each step rematerialised by itself, or each node (the plan before).

    python benchmarks/reverse_mode_plan.py [--fast-loops] [--steps 4000]

On XLA:CPU's default loop plan ``checkpoint=True`` (the default) rematerialises every step (DEP)
or every stage (splitting) by itself, in blocks whose largest leaf fits 512 bytes
(``vi_jax._saved_nodes.each_step_rematerialised``), and the splitting saves every node in blocks
of ``step_block`` nodes. The plan before rematerialised each node and each block of nodes, and
the splitting saved every node in blocks of 128. Both plans are compiled in one process (the
plan is chosen at trace time: patched while each program is traced, then compiled ahead of
time) and timed alternately, with the forward pass of the current plan and of
``checkpoint=False`` (forward passes and gradients apart); vehicle (DEP order 1
and Strang's splitting) and heavy top (splitting), ``jit``, float64, µs per step, with each
program's trace + compile time (after ``jax.clear_caches()``, the less of two). With
``--fast-loops`` the loop option is on: there ``vj.simulate`` keeps the node plan, and the
"each step" row forces the other plan to show what it would cost.
"""

import argparse
import contextlib
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json  # noqa: E402


@contextlib.contextmanager
def plan(each_step):
    """Trace with steps (``each_step``) or nodes rematerialised; the forward pass's blocks as the
    current plan has them."""
    from vi_jax import _saved_nodes
    from vi_jax.discrete import _splitting
    from vi_jax.engine import _advance

    real = _saved_nodes.default_cpu_loops
    saved = (_advance.default_cpu_loops, _advance._node_block, _splitting.default_cpu_loops)
    node_block = lambda state, every: _saved_nodes.step_block(state) if every == 1 and real() else _saved_nodes.SAVE_BLOCK  # noqa: E731
    _advance.default_cpu_loops = _splitting.default_cpu_loops = lambda: each_step
    _advance._node_block = node_block
    try:
        yield
    finally:
        _advance.default_cpu_loops, _advance._node_block, _splitting.default_cpu_loops = saved


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--out", default=None)
    args = parse_args_with_fast_loops(parser)
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import vi_jax as vj

    n = args.steps
    cases = [
        ("vehicle", "dep", n), ("vehicle", "dep", 10), ("vehicle", "dep", 1),
        ("vehicle", "splitting", 10), ("vehicle", "splitting", 1),
        ("heavy top", "splitting", 10), ("heavy top", "splitting", 1),
    ]  # fmt: skip
    models = {"vehicle": vj.models.UnderwaterVehicle(), "heavy top": vj.models.HeavyTop()}
    rows = []
    for scene, scheme, save_every in cases:
        model = models[scene]
        x0 = model.initial_state()
        dynamic, static = eqx.partition(model, eqx.is_array)

        def loss(d, checkpoint=True):
            sol = vj.simulate(
                eqx.combine(d, static), x0, 0.01, n, scheme=scheme, save_every=save_every, throw=False, checkpoint=checkpoint
            )
            q = sol.g if sol.q is None else sol.q
            return jnp.mean(q[-1] ** 2) if save_every == n else jnp.mean(q**2)

        programs, compile_s = {}, {}
        for name, fn, each_step in (
            ("forward", loss, True),
            ("forward, nodes rematerialised (plan before)", loss, False),
            ("forward, checkpoint=False", lambda d: loss(d, checkpoint=False), True),
            ("gradient, each step rematerialised", jax.value_and_grad(loss), True),
            ("gradient, each node rematerialised (plan before)", jax.value_and_grad(loss), False),
        ):
            with plan(each_step if not args.fast_loops or "gradient" in name else False):
                seconds = []
                for _ in range(2):  # the first trace after clear_caches also pays for shared helpers
                    jax.clear_caches()
                    start = time.perf_counter()
                    programs[name] = jax.jit(fn).lower(dynamic).compile()
                    seconds.append(time.perf_counter() - start)
                compile_s[name] = min(seconds)
        # Forward passes and gradients timed apart: a run of a few ms right after a large
        # program pays for the caches that program left (0.40 -> 0.51 us a step).
        calls = {k: (lambda p=p: p(dynamic)) for k, p in programs.items()}
        times = {}
        for kind in ("forward", "gradient"):
            times.update(time_alternately({k: c for k, c in calls.items() if k.startswith(kind)}))
        forward = times["forward"]
        for name, t in times.items():
            rows.append(dict(scene=scene, scheme=scheme, save_every=save_every, program=name, us_per_step=1e6 * t / n,
                             over_forward=t / forward, trace_and_compile_s=compile_s[name]))
            print(f"{scene:9s} {scheme:9s} every {save_every:5d}  {name:50s} {1e6 * t / n:7.2f} µs/step  {t / forward:6.2f}× forward"
                  f"  trace + compile {compile_s[name]:5.2f} s", flush=True)
    write_config_json("reverse_mode_plan", args.fast_loops, args.out, jax=jax.__version__, steps=n, rows=rows)


if __name__ == "__main__":
    main()
