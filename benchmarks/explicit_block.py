"""Unknowns solved before Newton in the generated batched step (``explicit_block``: rows of the
Jacobian affine in as many unknowns, the vehicle's ν at order 1, seed 000 eq. 74) against
Newton on every unknown, and both against the vehicle's hand-written batched step
(``_hand_vehicle_kernel.py``, seed 000 eqs. 73–74, the peer to reach): ``vj.ensemble`` of the
vehicle at order 1 (1024 members × 1000 steps, final node saved, Cayley, the CPU plan), with
parameters shared by the members and with a mass per member, the three variants compiled in
one process and timed alternately (median of 7 runs each).

    python benchmarks/explicit_block.py [--fast-loops]
"""

import argparse

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from _hand_vehicle_kernel import hand_kernel_ensemble  # noqa: E402
from vi_jax.engine import _member_newton  # noqa: E402

MEMBERS, STEPS, REPEATS, H = 1024, 1000, 7, 0.01
BLOCK = _member_newton.explicit_block


def compiled(systems, axes, states, variant):
    """The run compiled ahead of time for ``variant`` (caches cleared first: what it switches
    is read at trace time) and its final attitudes."""
    jax.clear_caches()
    _member_newton.explicit_block = BLOCK if variant == "generated, block" else lambda *args: None
    if variant == "hand kernel":
        run = jax.jit(lambda m, s, h: hand_kernel_ensemble(m, s, h, STEPS, save_every=STEPS, system_axes=axes))
    else:
        run = jax.jit(lambda m, s, h: vj.ensemble(m, s, h, STEPS, save_every=STEPS, system_axes=axes, method="batched", throw=False))
    run = run.lower(systems, states, jnp.asarray(H)).compile()
    return run, np.asarray(run(systems, states, jnp.asarray(H)).g[:, -1])


def main():
    model = vj.models.UnderwaterVehicle()
    states = perturbed_states(model.initial_state(), MEMBERS)
    rows = []
    try:
        for name, systems, axes in (("shared parameters", model, None),
                                    ("mass per member", vj.vary(model, mass=model.mass * np.linspace(0.98, 1.02, MEMBERS)), 0)):
            runs = {v: compiled(systems, axes, states, v) for v in ("generated, block", "generated, no block", "hand kernel")}
            seconds = time_alternately({v: lambda run=run: run(systems, states, jnp.asarray(H)) for v, (run, _) in runs.items()}, REPEATS)
            rate = {v: MEMBERS * STEPS / t for v, t in seconds.items()}
            diff = float(np.max(np.abs(runs["generated, block"][1] - runs["hand kernel"][1])))
            rows.append(dict(parameters=name, rates=rate, block_speedup=rate["generated, block"] / rate["generated, no block"],
                             block_over_kernel=rate["generated, block"] / rate["hand kernel"], max_abs_g_difference=diff))
            print(f"{name:18s}: " + ", ".join(f"{v} {r / 1e6:5.2f} M" for v, r in rate.items())
                  + f" member-steps/s; block {rows[-1]['block_speedup']:.2f}x, block / kernel {rows[-1]['block_over_kernel']:.2f}; "
                  f"max |g difference| {diff:.1e}", flush=True)
    finally:
        _member_newton.explicit_block = BLOCK
    write_config_json("explicit_block", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
