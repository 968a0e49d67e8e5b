"""A single trajectory through the generated batched step (``vj.ensemble`` with one member)
against ``vj.simulate``'s own step, both called on concrete inputs as users call them: the
vehicle and the heavy top at orders 1 and 2, 50,000 steps, a node saved at the end only, every
100 steps and every step (Cayley; h = 0.01 for the vehicle, 0.005 for the heavy top; median of
7 runs each, the two timed alternately in one process), and each one's first call (trace,
compile and run; in one process, so the later programs reuse what the earlier ones traced: the
first row's figures are the fair ones). The issue's step generator is meant to serve
``vj.simulate`` too: this measures what that would give, per XLA configuration.

    python benchmarks/one_member_generated.py [--fast-loops]
"""

import argparse
import time

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

ARGS = parse_args_with_fast_loops(argparse.ArgumentParser(description=__doc__.splitlines()[0]))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402

STEPS, REPEATS = 50_000, 7
SCENES = {"vehicle": (vj.models.UnderwaterVehicle, 0.01), "heavy_top": (vj.models.HeavyTop, 0.005)}


def main():
    rows = []
    for name, (scene, h) in SCENES.items():
        model = scene()
        x0 = model.initial_state()
        one = jax.tree.map(lambda x: None if x is None else jnp.asarray(x)[None], x0)
        for order in (1, 2):
            for every in (STEPS, 100, 1):
                calls = {
                    "ensemble, one member": lambda: vj.ensemble(model, one, h, STEPS, order=order, save_every=every),
                    "simulate": lambda: vj.simulate(model, x0, h, STEPS, order=order, save_every=every),
                }
                first, runs = {}, {}
                for label, call in calls.items():  # compile (a program per save layout) and warm up
                    start = time.perf_counter()
                    runs[label] = jax.block_until_ready(call())
                    first[label] = time.perf_counter() - start
                diff = float(np.max(np.abs(np.asarray(runs["ensemble, one member"].g[0]) - np.asarray(runs["simulate"].g))))
                seconds = time_alternately(calls, REPEATS)
                ratio = seconds["ensemble, one member"] / seconds["simulate"]
                rows.append(dict(scene=name, order=order, save_every=every, seconds=seconds, ratio=ratio, max_abs_g_difference=diff,
                                 first_call_s=first))
                print(f"{name:9s} order {order} save_every {every:6d}: ensemble(1 member) {seconds['ensemble, one member'] * 1e3:7.1f} ms, "
                      f"simulate {seconds['simulate'] * 1e3:7.1f} ms, ratio {ratio:.2f} (max |Δg| {diff:.1e}); first calls "
                      f"{first['ensemble, one member']:.2f} / {first['simulate']:.2f} s", flush=True)
    write_config_json("one_member_generated", ARGS.fast_loops, steps=STEPS, rows=rows)


if __name__ == "__main__":
    main()
