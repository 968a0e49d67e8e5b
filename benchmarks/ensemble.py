"""Ensemble throughput of the underwater vehicle (paper's Cayley scheme, h = 0.01, float64):
member-steps per second for 1, 64, 1024 and 8192 members.

    python benchmarks/ensemble.py [--members 1 64 1024 8192] [--out benchmarks/results/ensemble.json]

Implementations, timed in one process per XLA configuration (compiled code only; final state
returned, so saving costs nothing), alternately: one call of each per round, the median of 7
rounds (3 above 2·10⁷ member-steps a call), so that the peers share the machine's load (timed
one after another, the fastest call's five runs took 70 ms against the peer's 1.3 s: a busy
moment fell on one of them):

- ``plain vmap, hand step``: ``jax.vmap`` of the hand-specialised step of tests/hand_vehicle.py
  (eqs. 73–74 with 88, 3×3 matrices, three Newton iterations) — the peer;
- ``plain vmap, vj.simulate``: ``vj.ensemble(method="vmap")``, the generic engine under vmap;
- ``batched kernel``: ``vj.ensemble(method="batched")`` under ``jit``, members on the
  vectorised axis (the step generated from the Lagrangian; one program, one core, XLA's default
  compile options);
- ``batched, concrete call``: the same called on concrete inputs, as users call it (one group
  of members per core at the same time, or the members split over the mesh; the generated step
  compiled with ``ENSEMBLE_OPTIONS``: ``vi_jax/engine/_compile_options.py``).

XLA configurations: ``default`` (no flags), ``tuned``: XLA_FLAGS
``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000``, which lets
XLA:CPU compile a whole ``while`` loop into one kernel instead of dispatching each fused
operation separately (the dominant cost of small-array loops); ``tuned, sharded``: the same
with one XLA host device per core (``--xla_force_host_platform_device_count``), the members
split over them (``jax.shard_map`` for the hand step, ``ensemble(mesh=...)``), the peer being
the sharded hand step.
Rates are given per wall second
(this machine is shared: see ``cpu_rate``, per CPU second of this process, for the rate an
otherwise idle core would give).
"""

import argparse
import functools
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

HERE = Path(__file__).resolve().parent
DEVICES = f"--xla_force_host_platform_device_count={os.cpu_count()}"
CONFIGS = {"default": "", "tuned": FAST_LOOPS_FLAG, "tuned, sharded": f"{FAST_LOOPS_FLAG} {DEVICES}"}


def measure(members_list, config):
    """Run in a child process whose XLA_FLAGS are set: a JSON list of rows on stdout."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import vi_jax as vj
    from vi_jax.engine._ensemble import ensemble, vary

    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(HERE.parent / "tests"))
    from _timing import alternate_samples
    from hand_vehicle import make_step, vehicle_params

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    h = 0.01
    step = make_step(vehicle_params(model), h)
    mass = model.mass * jnp.eye(3) + model.added_mass

    def hand(omegas, n_steps):
        def one(w):
            carry = (x0.g, x0.q, model.inertia @ w, mass @ (x0.g.T @ x0.qdot), w)
            carry, _ = jax.lax.scan(lambda c, _: (step(c, None)[0], None), carry, None, length=n_steps)
            return carry[1]

        return jax.vmap(one)(omegas)

    rows = []
    for n in members_list:
        n_steps = 20_000 if n == 1 else 1000
        omegas = np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(n, 3))
        states = vary(x0, xi=omegas)
        impls = {
            "plain vmap, hand step": (jax.jit(lambda w, s=n_steps: hand(w, s)), jnp.asarray(omegas)),
        }
        n_dev = jax.device_count()
        if n_dev > 1:
            if n % n_dev:
                continue
            mesh = jax.make_mesh((n_dev,), ("members",))
            spec = jax.sharding.PartitionSpec("members")
            impls = {
                "plain vmap, hand step, sharded": (
                    jax.jit(jax.shard_map(lambda w, s=n_steps: hand(w, s), mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False)),
                    jax.device_put(jnp.asarray(omegas), jax.sharding.NamedSharding(mesh, spec)),
                ),
                "batched kernel, sharded": (
                    jax.jit(lambda x, s=n_steps: ensemble(model, x, h, s, save_every=s, mesh=mesh, throw=False).q[:, -1]),
                    states,
                ),
                "batched, concrete call, sharded": (
                    lambda x, s=n_steps: ensemble(model, x, h, s, save_every=s, mesh=mesh, throw=False).q[:, -1],
                    states,
                ),
            }
        else:
            impls |= {
                "plain vmap, vj.simulate": (
                    jax.jit(lambda x, s=n_steps: ensemble(model, x, h, s, save_every=s, method="vmap", throw=False).q[:, -1]),
                    states,
                ),
                "batched kernel": (
                    jax.jit(lambda x, s=n_steps: ensemble(model, x, h, s, save_every=s, method="batched", throw=False).q[:, -1]),
                    states,
                ),
                "batched, concrete call": (
                    lambda x, s=n_steps: ensemble(model, x, h, s, save_every=s, method="batched", throw=False).q[:, -1],
                    states,
                ),
            }
        outputs, first = {}, {}
        for name, (fn, arg) in impls.items():
            start = time.perf_counter()
            outputs[name] = np.asarray(jax.block_until_ready(fn(arg)))
            first[name] = time.perf_counter() - start
        samples = alternate_samples({name: functools.partial(fn, arg) for name, (fn, arg) in impls.items()}, 3 if n * n_steps > 2e7 else 7)
        for name, (fn, arg) in impls.items():
            median = statistics.median(samples[name])
            c0, t0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(fn(arg))
            cpu, wall = time.process_time() - c0, time.perf_counter() - t0
            rows.append(dict(
                config=config, members=n, steps=n_steps, implementation=name, compile_and_first_s=first[name],
                median_s=median, rate=n * n_steps / median, cpu_rate=n * n_steps / cpu, cpu_over_wall=cpu / wall,
            ))
            print(f"  [{config}] {n:5d} members  {name:28s} {n * n_steps / median / 1e6:8.3f} M member-steps/s", file=sys.stderr, flush=True)
        reference = outputs[next(iter(impls))]
        for row in rows[-len(impls):]:
            row["max_abs_q_difference_to_first"] = float(np.max(np.abs(outputs[row["implementation"]] - reference)))
        sol = ensemble(model, states, h, 200, save_every=10, method="batched")
        iterations = np.asarray(sol.newton_iterations)[:, 1:]
        rows[-1]["newton_iterations_mean"] = float(iterations.mean())
        rows[-1]["newton_iterations_max"] = int(iterations.max())
    return rows


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--members", type=int, nargs="+", default=[1, 64, 1024, 8192])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--out", default=str(HERE / "results" / "ensemble.json"))
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.members, args.child)))
        return

    rows = []
    for config in args.configs:
        env = dict(os.environ, XLA_FLAGS=CONFIGS[config], JAX_PLATFORMS="cpu")
        cmd = [sys.executable, __file__, "--child", config, "--members", *map(str, args.members)]
        run = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, text=True, check=True)
        rows += json.loads(run.stdout.strip().splitlines()[-1])

    peer = {(r["config"], r["members"]): r["rate"] for r in rows if r["implementation"].startswith("plain vmap, hand step")}
    print(f"\n{'config':11s} {'members':>7s} {'implementation':28s} {'M member-steps/s':>16s} {'per CPU-s':>10s} {'× peer':>7s}")
    for r in rows:
        r["ratio_to_plain_vmap_hand"] = r["rate"] / peer[(r["config"], r["members"])]
        print(
            f"{r['config']:11s} {r['members']:7d} {r['implementation']:28s} {r['rate'] / 1e6:16.3f} "
            f"{r['cpu_rate'] / 1e6:10.3f} {r['ratio_to_plain_vmap_hand']:7.1f}"
        )
    import jax

    from _timing import write_json

    write_json(args.out, {"jax": jax.__version__, "cpu_count": os.cpu_count(), "xla_flags": CONFIGS, "rows": rows})


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    main()
