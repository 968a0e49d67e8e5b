"""``vj.ensemble`` against a plain ``jax.vmap`` of ``vj.simulate`` (the issue's peer), CPU:
1024 members × 1000 steps, final node saved, compiled code only (scene, states and h as jit
arguments), median of 5, both timed in one process.

    python benchmarks/ensemble_vs_vmap.py [--members 1024] [--steps 1000] [--fast-loops]

Cases: vehicle (orders 1 and 2), heavy top (1, 2), rigid body (1, 2), Cayley. ``vj.ensemble``
takes its default path: the hand kernel for the vehicle at order 1, else the generated step.
"""

import argparse

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
            row = dict(scene=name, order=order, members=n, steps=steps, ensemble_s=t_ens, plain_vmap_s=t_plain,
                       ensemble_rate=n * steps / t_ens, plain_vmap_rate=n * steps / t_plain, ratio=t_plain / t_ens,
                       max_abs_difference=float(jnp.max(jnp.abs(g_ens - g_plain))))
            rows.append(row)
            print(f"{name:10s} order {order}: ensemble {row['ensemble_rate'] / 1e6:6.2f} M member-steps/s, "
                  f"plain vmap(simulate) {row['plain_vmap_rate'] / 1e6:6.2f} M: {row['ratio']:5.2f}x "
                  f"(max |ΔR| {row['max_abs_difference']:.1e})", flush=True)
    write_config_json("ensemble_vs_vmap", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
