"""``vj.ensemble`` against a plain ``jax.vmap`` of ``vj.simulate`` (the issue's peer), CPU:
1024 members × 1000 steps, final node saved, compiled code only, median of 5, timed in one
process: the peer and ``vj.ensemble`` under ``jit`` (scene, states and h as jit arguments: one
program, one core), and ``vj.ensemble`` called on concrete inputs as users call it (one group of
members per core, the groups at the same time: ``vi_jax/engine/_member_groups.py``), with its
CPU seconds per wall second.

    python benchmarks/ensemble_vs_vmap.py [--members 1024] [--steps 1000] [--fast-loops]

Cases: vehicle (orders 1 and 2), heavy top (1, 2), rigid body (1, 2), Cayley. ``vj.ensemble``
takes its default path, the step generated from the scene's Lagrangian.
"""

import argparse
import os
import statistics
import time

from _timing import parse_args_with_fast_loops, time_compiled, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=1024)
PARSER.add_argument("--steps", type=int, default=1000)
ARGS = parse_args_with_fast_loops(PARSER)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402

SCENES = {"vehicle": (vj.models.UnderwaterVehicle, 0.01), "heavy_top": (vj.models.HeavyTop, 0.005), "rigid_body": (vj.models.RigidBody, 0.01)}


def time_concrete(call, repeats=5):
    """(median seconds, median CPU seconds per wall second, last output) of a concrete call,
    after a first call that compiles."""
    out = jax.block_until_ready(call())
    walls, loads = [], []
    for _ in range(repeats):
        cpu, start = os.times(), time.perf_counter()
        out = jax.block_until_ready(call())
        walls.append(time.perf_counter() - start)
        end = os.times()
        loads.append((end.user + end.system - cpu.user - cpu.system) / walls[-1])
    return statistics.median(walls), statistics.median(loads), out


def main():
    n, steps = ARGS.members, ARGS.steps
    rows = []
    for name, (scene, h) in SCENES.items():
        model = scene()
        x0 = model.initial_state()
        states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(n, 3)))
        for order in (1, 2):
            ensemble = eqx.filter_jit(
                lambda m, s, h, order=order: vj.ensemble(m, s, h, steps, order=order, save_every=steps, throw=False).g[:, -1]
            )
            plain = eqx.filter_jit(
                lambda m, s, h, order=order: jax.vmap(
                    lambda x: vj.simulate(m, x, h, steps, order=order, save_every=steps, throw=False).g[-1]
                )(s)
            )
            h_ = jnp.asarray(h)
            _, t_ens, g_ens = time_compiled(ensemble, model, states, h_, repeats=5)
            _, t_plain, g_plain = time_compiled(plain, model, states, h_, repeats=5)
            t_conc, cpu_conc, g_conc = time_concrete(
                lambda order=order: vj.ensemble(model, states, h, steps, order=order, save_every=steps, throw=False).g[:, -1]
            )
            row = dict(scene=name, order=order, members=n, steps=steps, ensemble_s=t_ens, plain_vmap_s=t_plain,
                       ensemble_rate=n * steps / t_ens, plain_vmap_rate=n * steps / t_plain, ratio=t_plain / t_ens,
                       concrete_s=t_conc, concrete_rate=n * steps / t_conc, concrete_ratio=t_plain / t_conc,
                       concrete_cpu_over_wall=cpu_conc,
                       max_abs_difference=float(max(jnp.max(jnp.abs(g - g_plain)) for g in (g_ens, g_conc))))
            rows.append(row)
            print(f"{name:10s} order {order}: plain vmap(simulate) {row['plain_vmap_rate'] / 1e6:6.2f} M member-steps/s; "
                  f"ensemble under jit {row['ensemble_rate'] / 1e6:6.2f} M ({row['ratio']:5.2f}x), "
                  f"concrete {row['concrete_rate'] / 1e6:6.2f} M ({row['concrete_ratio']:5.2f}x, cpu/wall {cpu_conc:.2f}) "
                  f"(max |ΔR| {row['max_abs_difference']:.1e})", flush=True)
    write_config_json("ensemble_vs_vmap", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
