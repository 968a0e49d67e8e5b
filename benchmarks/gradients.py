"""Gradients through long trajectories of the underwater vehicle (Cayley, h = 0.01, float64):
the time of a gradient as a multiple of the forward pass, and memory against the number of steps.

    python benchmarks/gradients.py [--sizes 1000 10000 100000 1000000] [--out benchmarks/results/gradients.json]

Part 1 — time, 10⁴ steps, one process per XLA configuration (``default``; ``tuned``: XLA_FLAGS
``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000``). Losses:
``final`` (the final position and attitude; ``save_every = n_steps``) and ``trajectory`` (the
mean |q|² over nodes saved every 10 steps). Rows: reverse mode (``jax.value_and_grad`` w.r.t. all
parameters) with and without ``checkpoint``; forward mode: one ``jvp`` and the least-squares
Jacobian (``jacfwd`` of the saved positions w.r.t. the 11 parameters of vi_jax.fitting._parametrisation). Each time
is divided by the forward pass (the loss alone).

Part 2 — memory, a fresh process per (loss, variant, number of steps, configuration): ``plain``
under the ``tuned`` flags, ``checkpoint`` under both (on XLA:CPU's default loop plan each step is
rematerialised by itself, vi_jax._saved_nodes.each_step_rematerialised): XLA's compiled memory analysis of the
jitted gradient (temporary buffers) and the peak resident memory above the process's baseline
(``resource.getrusage``), with the gradient/forward time ratio. Variants: ``plain``,
``checkpoint`` (``simulate(checkpoint=True)``: blockwise rematerialisation over blocks of 128
saved nodes, the steps between two saved nodes in √save_every rematerialised blocks).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

HERE = Path(__file__).resolve().parent
CONFIGS = {"default": "", "tuned": FAST_LOOPS_FLAG}
H = 0.01


def _setup():
    import jax

    jax.config.update("jax_enable_x64", True)
    import equinox as eqx

    import vi_jax as vj

    model = vj.models.UnderwaterVehicle()
    dynamic, static = eqx.partition(model, eqx.is_array)
    return model, model.initial_state(), dynamic, static


def _loss(kind, n_steps, checkpoint, x0, static):
    import equinox as eqx
    import jax.numpy as jnp

    import vi_jax as vj

    save_every = n_steps if kind == "final" else (10 if kind == "trajectory" else 1)

    def loss(dynamic):
        sol = vj.simulate(eqx.combine(dynamic, static), x0, H, n_steps, save_every=save_every, checkpoint=checkpoint, throw=False)
        if kind == "final":
            return jnp.sum(sol.q[-1] ** 2) + jnp.sum(sol.R[-1, 2])
        return jnp.mean(jnp.sum(sol.q**2, axis=-1))

    return loss


def time_rows(config, n_steps=10_000):
    """Part 1 (run in a child process with the configuration's XLA_FLAGS)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import vi_jax as vj
    from vi_jax.fitting import Parametrisation

    sys.path.insert(0, str(HERE))
    from _timing import time_compiled

    model, x0, dynamic, static = _setup()
    rows = []
    for kind in ("final", "trajectory"):
        forward = jax.jit(_loss(kind, n_steps, False, x0, static))
        first, t_fwd, _ = time_compiled(forward, dynamic)
        rows.append(dict(config=config, loss=kind, mode="forward pass", compile_and_first_s=first, median_s=t_fwd, ratio=1.0))
        for checkpoint in (False, True):
            grad = jax.jit(jax.value_and_grad(_loss(kind, n_steps, checkpoint, x0, static)))
            first, t, _ = time_compiled(grad, dynamic)
            mode = "reverse (value_and_grad)" + (", checkpoint" if checkpoint else "")
            rows.append(dict(config=config, loss=kind, mode=mode, compile_and_first_s=first, median_s=t, ratio=t / t_fwd))
        tangent = jax.tree.map(lambda x: jnp.ones_like(x) * 1e-3, dynamic)
        jvp = jax.jit(lambda d, t, f=_loss(kind, n_steps, False, x0, static): jax.jvp(f, (d,), (t,)))
        first, t, _ = time_compiled(jvp, dynamic, tangent)
        rows.append(dict(config=config, loss=kind, mode="forward (jvp, one direction)", compile_and_first_s=first, median_s=t, ratio=t / t_fwd))
    param = Parametrisation(model)
    save_every = 10

    def positions(theta):
        return vj.simulate(param.decode(theta), x0, H, n_steps, save_every=save_every, throw=False).q

    theta = param.encode(model)
    first, t_fwd, _ = time_compiled(jax.jit(positions), theta)
    first_j, t_j, J = time_compiled(jax.jit(jax.jacfwd(positions)), theta)
    rows.append(dict(
        config=config, loss="trajectory", mode=f"forward (jacfwd, {theta.size} parameters)", compile_and_first_s=first_j,
        median_s=t_j, ratio=t_j / t_fwd, jacobian_shape=list(np.shape(J)),
    ))
    return rows


def memory_row(kind, variant, n_steps):
    """Part 2 (run in a fresh child process)."""
    import jax

    model, x0, dynamic, static = _setup()
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    checkpoint = variant != "plain"
    loss = _loss(kind, n_steps, checkpoint, x0, static)
    grad = jax.jit(jax.grad(loss)).lower(dynamic).compile()
    analysis = grad.memory_analysis()
    forward = jax.jit(loss).lower(dynamic).compile()
    jax.block_until_ready(forward(dynamic))
    compiled_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    jax.block_until_ready(forward(dynamic))
    t_fwd = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(grad(dynamic))
    t_grad = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return dict(
        loss=kind, variant=variant, steps=n_steps, temp_bytes=analysis.temp_size_in_bytes,
        output_bytes=analysis.output_size_in_bytes, peak_rss_above_baseline_bytes=(peak - baseline) * 1024,
        peak_rss_above_compiled_bytes=(peak - compiled_rss) * 1024, forward_s=t_fwd, gradient_s=t_grad, ratio=t_grad / t_fwd,
    )


def _child(args, flags):
    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    run = subprocess.run([sys.executable, __file__, *args], env=env, stdout=subprocess.PIPE, text=True, check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000, 1_000_000])
    parser.add_argument("--out", default=str(HERE / "results" / "gradients.json"))
    parser.add_argument("--child-time", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--child-memory", nargs=3, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_time:
        print(json.dumps(time_rows(args.child_time)))
        return
    if args.child_memory:
        kind, variant, n = args.child_memory
        print(json.dumps(memory_row(kind, variant, int(n))))
        return

    timing = []
    for config, flags in CONFIGS.items():
        timing += _child(["--child-time", config], flags)
    print(f"\n{'config':8s} {'loss':11s} {'mode':40s} {'median [ms]':>12s} {'× forward':>10s}")
    for r in timing:
        print(f"{r['config']:8s} {r['loss']:11s} {r['mode']:40s} {1e3 * r['median_s']:12.2f} {r['ratio']:10.2f}")

    memory = []
    for kind, variants in (("final", ("plain", "checkpoint")), ("every-step", ("plain", "checkpoint"))):
        for variant in variants:
            for n, config in [(n, c) for c in (("tuned",) if variant == "plain" else CONFIGS) for n in args.sizes]:
                row = dict(config=config, **_child(["--child-memory", kind, variant, str(n)], CONFIGS[config]))
                memory.append(row)
                print(
                    f"  {kind:10s} {variant:10s} {config:8s} {n:>9d} steps: temp {row['temp_bytes'] / 1e6:10.2f} MB, "
                    f"peak RSS +{row['peak_rss_above_baseline_bytes'] / 1e6:9.1f} MB, gradient {row['ratio']:.2f}× forward",
                    flush=True,
                )
    print("\nGrowth of XLA's temporary memory per ×10 steps (final-state loss):")
    for variant in ("plain", "checkpoint"):
        temps = [r["temp_bytes"] for r in memory if r["loss"] == "final" and r["variant"] == variant and r["config"] == "tuned"]
        factors = [b / a for a, b in zip(temps, temps[1:])]
        print(f"  {variant:10s} " + "  ".join(f"×{f:.2f}" for f in factors))
    import jax

    from _timing import write_json

    write_json(args.out, {"jax": jax.__version__, "h": H, "xla_flags": CONFIGS, "timing": timing, "memory": memory})


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    main()
