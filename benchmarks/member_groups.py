"""What a concrete ``vj.ensemble`` call gains from one group of members per core
(``vi_jax/engine/_member_groups.py``), and the one scene where the optimistic plan costs speed:
1024 members × 1000 steps, Cayley, peers timed alternately in one process (median of 5).

    python benchmarks/member_groups.py [--fast-loops]

- Groups: a concrete call with one group per core against the same call in one group, saving
  the final node, every fourth node and every node (heavy top, order 1; rigid body, order 2);
  groups forced where ``vj.ensemble`` would not use them (``MIN_STEPS_PER_NODE``: what decided it).
- Newton's full iterations: ``vj.ensemble`` under ``jit`` with ``max_newton_iterations=3``
  (the optimistic plan's first program: no fallback compiled) against the default 20, for the
  scenes of ``benchmarks/ensemble_vs_vmap.py``' generated step, with each program's CPU seconds
  per wall second, here and in a child process bound to one core (``--one-core``): XLA:CPU's
  thunk executor may run a program's independent fusions on several threads, and where it
  does, the cost of handing tiny fusions between threads shows.
"""

import argparse
import json
import os
import subprocess
import sys

from _timing import cpu_per_wall, parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--one-core", action="store_true", help="only the fallback rows, printed as JSON (bind to one core first)")
ARGS = parse_args_with_fast_loops(PARSER)
if ARGS.one_core:  # before JAX starts its backend, which sizes its thread pool from the cores allowed
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax.engine import _member_groups  # noqa: E402

MEMBERS, STEPS, REPEATS = 1024, 1000, 5
CORES, MIN_STEPS_PER_NODE = _member_groups.cores, _member_groups.MIN_STEPS_PER_NODE


def groups_rows():
    rows = []
    for scene, order, h in (("HeavyTop", 1, 0.005), ("RigidBody", 2, 0.01)):
        model = getattr(vj.models, scene)()
        states = perturbed_states(model.initial_state(), MEMBERS)
        for save_every in (STEPS, 4, 1):
            def call(cores, save_every=save_every):
                _member_groups.cores, _member_groups.MIN_STEPS_PER_NODE = (lambda: cores), 1
                try:
                    return vj.ensemble(model, states, h, STEPS, order=order, save_every=save_every, throw=False).g
                finally:
                    _member_groups.cores, _member_groups.MIN_STEPS_PER_NODE = CORES, MIN_STEPS_PER_NODE

            calls = {"one group": lambda: call(1), "one group per core": lambda: call(CORES())}
            for c in calls.values():
                jax.block_until_ready(c())
            seconds = time_alternately(calls, REPEATS)
            rate = {k: MEMBERS * STEPS / t for k, t in seconds.items()}
            rows.append(dict(scene=scene, order=order, save_every=save_every, cores=CORES(), rates=rate,
                             ratio=rate["one group per core"] / rate["one group"]))
            print(f"{scene:10s} order {order}, save_every={save_every:4d}: " + ", ".join(f"{k} {r / 1e6:6.2f} M" for k, r in rate.items())
                  + f" member-steps/s: {rows[-1]['ratio']:.2f}x", flush=True)
    return rows


def fallback_rows():
    rows = []
    for scene, order, h in (("RigidBody", 1, 0.01), ("RigidBody", 2, 0.01), ("HeavyTop", 1, 0.005), ("HeavyTop", 2, 0.005)):
        model = getattr(vj.models, scene)()
        states = perturbed_states(model.initial_state(), MEMBERS)
        calls = {}
        for most in (20, 3):
            run = eqx.filter_jit(lambda m, s, h, most=most: vj.ensemble(
                m, s, h, STEPS, order=order, save_every=STEPS, throw=False, max_newton_iterations=most).g[:, -1])
            calls[f"max_newton_iterations={most}"] = lambda run=run: run(model, states, jnp.asarray(h))
        for c in calls.values():
            jax.block_until_ready(c())
        seconds = time_alternately(calls, REPEATS)
        rate = {k: MEMBERS * STEPS / t for k, t in seconds.items()}
        cpu = {k: cpu_per_wall(c) for k, c in calls.items()}
        rows.append(dict(scene=scene, order=order, cores=len(os.sched_getaffinity(0)), rates=rate, cpu_per_wall=cpu,
                         ratio=rate["max_newton_iterations=3"] / rate["max_newton_iterations=20"]))
        print(f"{scene:10s} order {order}, under jit, {rows[-1]['cores']} core(s): "
              + ", ".join(f"{k} {r / 1e6:6.2f} M ({cpu[k]:.2f} CPU s/s)" for k, r in rate.items())
              + f" member-steps/s: without / with the fallback {rows[-1]['ratio']:.2f}x", flush=True, file=sys.stderr if ARGS.one_core else sys.stdout)
    return rows


def fallback_rows_on_one_core():
    """:func:`fallback_rows` in a child process bound to one core."""
    argv = [sys.executable, __file__, "--one-core"] + (["--fast-loops"] if ARGS.fast_loops else [])
    run = subprocess.run(argv, stdout=subprocess.PIPE, text=True, check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    if ARGS.one_core:
        print(json.dumps(fallback_rows()))
    else:
        write_config_json("member_groups", ARGS.fast_loops, groups=groups_rows(), fallback=fallback_rows(),
                          fallback_on_one_core=fallback_rows_on_one_core())
