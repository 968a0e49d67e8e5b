"""Cost per time step of the beam's time march against the number of nodes (seed 003, spec §6).

Each step is one 6-dim Newton solve per node, batched with ``vmap`` inside ``lax.scan``; the cost
should grow linearly with the number of nodes. As a peer in the same process, the same engine
with the node solves run one after the other (``lax.map``) shows what the batching buys.
Compiled code only: warm-up, ``block_until_ready``, median of ``--repeats`` runs; compile time
reported separately.

  python benchmarks/beam.py [--nodes 4 8 16 ...] [--steps 500] [--repeats 7]
                            [--out benchmarks/results/beam.json]

prints a table, writes the JSON and a PNG next to it (same stem).
"""

import argparse
import dataclasses
import platform
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from vi_jax.lie import difference_map  # noqa: E402
from vi_jax.models._beam import GeometricallyExactBeam  # noqa: E402
from vi_jax.multisymplectic import _march  # noqa: E402
from vi_jax.multisymplectic._time import _start, default_rtol  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import time_compiled, write_json  # noqa: E402


class SequentialEngine(_march.Engine):
    """The peer: the same node solves, one node after the other (``lax.map``) instead of ``vmap``."""

    def solve(self, c, v0):
        rest = jnp.max(jnp.abs(self.evolution_momentum(jnp.zeros_like(v0[0]))))
        v, (iterations, residual, result) = jax.lax.map(lambda a: _march._node_solve(self, *a, rest), (c, v0))
        return v, (iterations.astype(jnp.int32), residual, result.astype(jnp.int8))


def _march_fn(engine_cls, n_steps):
    def run(model, g0, xi0, dt, ds):
        engine, carry = _start(
            model, g0, xi0, None, dt, ds, boundary="free-free", force=None, tau=difference_map("cayley"),
            rtol=default_rtol(g0.dtype), max_iterations=20,
        )
        engine = engine_cls(**{f.name: getattr(engine, f.name) for f in dataclasses.fields(engine)})
        rows = _march.run(engine, carry, n_steps, 1)
        return rows.m, jnp.mean(rows.iterations), jnp.max(rows.result)

    return eqx.filter_jit(run)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[4, 8, 16, 32, 64, 128, 256, 512])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-sequential", action="store_true", help="skip the lax.map peer")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/beam.json"))
    args = parser.parse_args(argv)
    if args.repeats < 5:
        parser.error("--repeats: at least 5 (median of ≥ 5 runs)")

    model = GeometricallyExactBeam()
    vmapped = _march_fn(_march.Engine, args.steps)
    sequential = None if args.no_sequential else _march_fn(SequentialEngine, args.steps)
    rows = []
    header = f"{'nodes':>6} {'µs/step':>10} {'ns/node-step':>13} {'compile s':>10} {'Newton it.':>10}"
    header += "" if sequential is None else f" {'lax.map µs/step':>16} {'ratio':>6}"
    print(f"beam time march, free–free, {args.steps} steps, Δt = ½ stability limit; {jax.devices()[0].platform}")
    print(header)
    for n in args.nodes:
        ds = float(model.length) / n
        dt = 0.5 * float(model.stable_time_step(ds))
        g0, xi0 = model.initial_state(n)
        call = (model, g0, xi0, jnp.asarray(dt), jnp.asarray(ds))
        first, seconds, (_, iterations, failed) = time_compiled(vmapped, *call, repeats=args.repeats)
        compile_s = first - seconds
        if int(failed):
            raise RuntimeError(f"a Newton solve failed at {n} nodes")
        row = dict(
            nodes=n, dt=dt, us_per_step=1e6 * seconds / args.steps, ns_per_node_step=1e9 * seconds / (args.steps * n),
            compile_s=compile_s, newton_iterations_mean=float(iterations),
        )
        line = f"{n:>6} {row['us_per_step']:>10.1f} {row['ns_per_node_step']:>13.0f} {compile_s:>10.2f} {float(iterations):>10.2f}"
        if sequential is not None:
            seq_first, seq_seconds, _ = time_compiled(sequential, *call, repeats=args.repeats)
            row.update(sequential_us_per_step=1e6 * seq_seconds / args.steps, sequential_compile_s=seq_first - seq_seconds)
            line += f" {row['sequential_us_per_step']:>16.1f} {seq_seconds / seconds:>6.2f}"
        rows.append(row)
        print(line, flush=True)

    nodes = np.array([r["nodes"] for r in rows], float)
    cost = np.array([r["us_per_step"] for r in rows])
    large = nodes >= min(32, nodes.max())
    exponent = float(np.polyfit(np.log(nodes[large]), np.log(cost[large]), 1)[0]) if large.sum() >= 2 else float("nan")
    print(f"fitted exponent of µs/step against nodes (nodes ≥ {int(nodes[large].min())}): {exponent:.2f}")
    result = dict(
        benchmark="beam time march: cost per step against nodes",
        command="python benchmarks/beam.py " + " ".join(argv or []),
        machine=platform.platform(), processor=platform.processor(), device=str(jax.devices()[0]),
        jax_version=jax.__version__, steps=args.steps, repeats=args.repeats, rows=rows,
        fitted_exponent=exponent,
    )
    write_json(args.out, result)
    _plot(rows, exponent, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.png')}")


def _plot(rows, exponent, path):
    from matplotlib.figure import Figure

    nodes = np.array([r["nodes"] for r in rows], float)
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    ax.loglog(nodes, [r["us_per_step"] for r in rows], "o-", label=f"vmap (exponent {exponent:.2f})")
    if "sequential_us_per_step" in rows[0]:
        ax.loglog(nodes, [r["sequential_us_per_step"] for r in rows], "s--", label="lax.map (sequential nodes)")
    ax.loglog(nodes, rows[-1]["us_per_step"] * nodes / nodes[-1], ":", color="gray", label="linear")
    ax.set_xlabel("nodes")
    ax.set_ylabel("µs per time step")
    ax.set_title("beam time march: cost per step")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
