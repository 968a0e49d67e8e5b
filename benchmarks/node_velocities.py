"""Node velocities of a saved trajectory (``vi_jax.engine._node_velocities.node_velocities``: the
continuous inverse Legendre map at every node, on component arrays of shape (nodes,)) for 50,001
nodes of the vehicle and the heavy top, compiled calls timed alternately (median of 11); the
vehicle's peer is its velocities written out by hand, ω = J⁻¹M and ν = (mI + M_A)⁻¹P
(tests/hand_vehicle.py), whose matrix products are the floor of this computation.

    python benchmarks/node_velocities.py [--fast-loops] [--out PATH]

To compare versions, run it with another version of the package first on ``PYTHONPATH`` (and
``--out`` elsewhere), in alternate processes.
"""

import argparse
import sys
from pathlib import Path

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--out", default=None, help="JSON path (default: benchmarks/results/node_velocities[_fast_loops].json)")
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax.engine import _advance, _simulate  # noqa: E402
from vi_jax.engine._node_velocities import node_velocities  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from hand_vehicle import inv3  # noqa: E402

N_STEPS, H, RTOL = 50_000, 0.01, 64 * float(np.finfo(np.float64).eps)
SCENES = {"vehicle": vj.models.UnderwaterVehicle, "heavy_top": vj.models.HeavyTop}


def saved_states(model):
    """The step states (g, q, M, P and the unknowns z) of every node of a 50,000-step run."""
    tau = vj.lie.difference_map("cayley")
    run = jax.jit(lambda m, x: _advance.advance_scan(m, tau, "left", (1.0,), jnp.asarray(H), _simulate._initial(m, x), N_STEPS, 1, RTOL, 20))
    return run(model, model.initial_state())[1]


def main():
    calls, programs = {}, {}
    for name, scene in SCENES.items():
        model = scene()
        states = saved_states(model)
        programs[name] = jax.jit(lambda m, s: node_velocities(m, s, RTOL, 20)).lower(model, states).compile()
        calls[f"{name}, node_velocities"] = lambda p=programs[name], m=model, s=states: p(m, s)
        if name == "vehicle":
            hand = lambda m, s: (s.M @ inv3(m.inertia).T, s.P @ inv3(m.mass * jnp.eye(3) + m.added_mass).T)  # noqa: E731
            ours, theirs = programs[name](model, states), jax.jit(hand)(model, states)
            difference = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(ours, theirs))
            hand_program = jax.jit(hand).lower(model, states).compile()
            calls["vehicle, by hand (matrix products)"] = lambda p=hand_program, m=model, s=states: p(m, s)
    medians = time_alternately(calls, repeats=11)
    for name, seconds in medians.items():
        print(f"{name:40s} {seconds * 1e3:8.3f} ms")
    print(f"vehicle: max |ours − by hand| = {difference:.2e}")
    write_config_json("node_velocities", ARGS.fast_loops, ARGS.out, nodes=N_STEPS + 1, jax=jax.__version__,
                      medians_ms={k: v * 1e3 for k, v in medians.items()}, max_abs_difference_to_hand=difference)


if __name__ == "__main__":
    main()
