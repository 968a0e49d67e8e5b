"""``vj.ensemble``'s CPU plan with and without its compile options (``ENSEMBLE_OPTIONS``,
``vi_jax/engine/_compile_options.py``): copy insertion by region analysis, 512-bit vectors, each
alone and both, against XLA's defaults, in one process.

    python benchmarks/ensemble_compile_options.py [--members 1024] [--steps 1000] [--fast-loops]

Each case is a concrete call as users make it (1024 members × 1000 steps, final node saved; the
members in one group per core), its program compiled once per variant; the variants are timed
one after another, 7 times (median). Every variant's states must equal the default's bitwise:
the options change copies and vector width, not arithmetic. Cases: the generated step (vehicle,
heavy top, rigid body, orders 1 and 2) and the plain ``vmap`` path (rigid body, order 2), which
keeps XLA's defaults in ``vj.ensemble``: its dots and reductions, 512 bits wide, round
differently (the row says so).
"""

import argparse

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--members", type=int, default=1024)
PARSER.add_argument("--steps", type=int, default=1000)
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax.engine import _compile_options, _ensemble  # noqa: E402

REGION, WIDTH = _compile_options.ENSEMBLE_OPTIONS
VARIANTS = {
    "XLA's defaults": {},
    "region analysis": {REGION: _compile_options.ENSEMBLE_OPTIONS[REGION]},
    "512-bit vectors": {WIDTH: _compile_options.ENSEMBLE_OPTIONS[WIDTH]},
    "both (vi_jax's)": dict(_compile_options.ENSEMBLE_OPTIONS),
}
CASES = [(scene, h, order, "batched") for scene, h in (("UnderwaterVehicle", 0.01), ("HeavyTop", 0.005), ("RigidBody", 0.01)) for order in (1, 2)]
CASES.append(("RigidBody", 0.01, 2, "vmap"))


def main():
    n, steps = ARGS.members, ARGS.steps
    programs = {name: _compile_options.cpu_options_jit(_ensemble._run_loop.__wrapped__, opts) for name, opts in VARIANTS.items()}
    rows = []
    for scene, h, order, method in CASES:
        model = getattr(vj.models, scene)()
        x0 = model.initial_state()
        states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(n, 3)))

        def call(program):
            _ensemble._run_loop = _ensemble._vmap_loop = program
            return vj.ensemble(model, states, h, steps, order=order, save_every=steps, method=method, throw=False).g

        finals = {name: np.asarray(call(program)) for name, program in programs.items()}  # compiles
        times = time_alternately({name: lambda p=program: call(p) for name, program in programs.items()})
        base = times["XLA's defaults"]
        row = dict(scene=scene, order=order, method=method, members=n, steps=steps,
                   seconds=times, speedup={name: base / t for name, t in times.items()},
                   bitwise_equal={name: bool(np.array_equal(f, finals["XLA's defaults"], equal_nan=True)) for name, f in finals.items()})
        rows.append(row)
        print(f"{scene:17s} order {order} {method:7s} " + "  ".join(
            f"{name}: {1e3 * t:7.1f} ms ({row['speedup'][name]:.2f}x{'' if row['bitwise_equal'][name] else ', DIFFERS'})" for name, t in times.items()
        ), flush=True)
    write_config_json("ensemble_compile_options", ARGS.fast_loops, options=_compile_options.ENSEMBLE_OPTIONS, rows=rows)


if __name__ == "__main__":
    main()
