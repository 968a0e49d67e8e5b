"""``vj.ensemble`` against a plain ``jax.vmap`` of ``vj.simulate`` (the issue's peer), CPU:
1024 members × 1000 steps, final node saved, compiled code only, timed in one process: the peer
and ``vj.ensemble`` under ``jit`` (scene, states and h as jit arguments: one program, one core),
and ``vj.ensemble`` called on concrete inputs as users call it (one group of members per core,
the groups at the same time: ``vi_jax/engine/_member_groups.py``). The three are timed
alternately, one call of each per round, the median of 7 rounds (the peers share the machine's
load: timed one after another, the peer's 0.3–0.5 s calls and the ensemble's 0.04 s ones met
different moments of a shared machine, the peer's rate varying 2× between runs), then each one's
CPU seconds per wall second (the peer's too, which XLA runs partly on a second thread).

    python benchmarks/ensemble_vs_vmap.py [--members 1024] [--steps 1000] [--scenes vehicle heavy_top rigid_body]
        [--fast-loops]

Cases: vehicle (orders 1 and 2), heavy top (1, 2), rigid body (1, 2), Cayley. ``vj.ensemble``
takes its default path, the step generated from the scene's Lagrangian.
"""

import argparse
import functools
import time

from _timing import cpu_per_wall, machine, parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=1024)
PARSER.add_argument("--steps", type=int, default=1000)
SCENE_NAMES = ("vehicle", "heavy_top", "rigid_body")  # SCENES' keys: the options are parsed before vi_jax is imported
PARSER.add_argument("--scenes", nargs="+", default=list(SCENE_NAMES), choices=SCENE_NAMES)
ARGS = parse_args_with_fast_loops(PARSER)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402

SCENES = {"vehicle": (vj.models.UnderwaterVehicle, 0.01), "heavy_top": (vj.models.HeavyTop, 0.005), "rigid_body": (vj.models.RigidBody, 0.01)}


def main():
    n, steps = ARGS.members, ARGS.steps
    rows = []
    for name in ARGS.scenes:
        scene, h = SCENES[name]
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
            calls = {
                "plain_vmap": functools.partial(plain, model, states, h_),
                "ensemble": functools.partial(ensemble, model, states, h_),
                "concrete": lambda order=order: vj.ensemble(model, states, h, steps, order=order, save_every=steps, throw=False).g[:, -1],
            }
            finals = {key: jax.block_until_ready(call()) for key, call in calls.items()}  # compiles
            seconds = time_alternately(calls, repeats=7)
            load = {key: cpu_per_wall(call) for key, call in calls.items()}
            row = dict(scene=name, order=order, members=n, steps=steps)
            for key, t in seconds.items():
                row.update({f"{key}_s": t, f"{key}_rate": n * steps / t, f"{key}_cpu_over_wall": load[key]})
            row.update(ratio=seconds["plain_vmap"] / seconds["ensemble"], concrete_ratio=seconds["plain_vmap"] / seconds["concrete"],
                       max_abs_difference=float(max(jnp.max(jnp.abs(finals[k] - finals["plain_vmap"])) for k in ("ensemble", "concrete"))))
            rows.append(row)
            print(f"{name:10s} order {order}: plain vmap(simulate) {row['plain_vmap_rate'] / 1e6:6.2f} M member-steps/s "
                  f"(cpu/wall {load['plain_vmap']:.2f}); ensemble under jit {row['ensemble_rate'] / 1e6:6.2f} M "
                  f"({row['ratio']:5.2f}x, cpu/wall {load['ensemble']:.2f}), "
                  f"concrete {row['concrete_rate'] / 1e6:6.2f} M ({row['concrete_ratio']:5.2f}x, cpu/wall {load['concrete']:.2f}) "
                  f"(max |ΔR| {row['max_abs_difference']:.1e})", flush=True)
    write_config_json("ensemble_vs_vmap", ARGS.fast_loops, date=time.strftime("%Y-%m-%d"), machine=machine(), timing="alternate", rows=rows)


if __name__ == "__main__":
    main()
