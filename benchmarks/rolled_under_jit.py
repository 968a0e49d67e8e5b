"""``vj.simulate`` under ``jit`` with the concrete call's step where it fits one kernel
(``vi_jax/engine/_advance.py``, ``_value_step``: Newton's iterations rolled, a composition's
sub-steps a loop of traced count; gradients rolled with the loop option only) against the same
programs with the step of static counts (the plan before; the rows' ``unrolled_*``):
forward runs (20,000 steps, every node saved) of orders 1, 2, 4 and 6, and reverse-mode
gradients (4,000 steps, a node every 10 steps, the final position's (the attitude's) sum by the
scene's parameters) of orders 1 and 2, every program compiled under its plan, the peers timed
alternately in one process (median of ``--repeats``). Also each program's first call (trace,
compile and run) in seconds.

    python benchmarks/rolled_under_jit.py [--fast-loops] [--repeats 7]
"""

import argparse
from unittest import mock

from _timing import compiled_under, parse_args_with_fast_loops, time_alternately, write_config_json

PARSER = argparse.ArgumentParser()
PARSER.add_argument("--repeats", type=int, default=7)
ARGS = parse_args_with_fast_loops(PARSER)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax.engine import _advance  # noqa: E402

FORWARD_STEPS, GRADIENT_STEPS, GRADIENT_SAVE_EVERY = 20_000, 4_000, 10
CASES = [("UnderwaterVehicle", 0.01), ("HeavyTop", 0.005), ("RigidBody", 0.01)]
PLANS = {"rolled": (), "unrolled": (mock.patch.object(_advance, "_value_step", lambda make_step, gammas, carry: None),)}
FORWARD_ORDERS, GRADIENT_ORDERS = (1, 2, 4, 6), (1, 2)


def main():
    first, calls = {}, {}
    model = vj.models.UnderwaterVehicle()
    compiled_under(lambda m, x: vj.simulate(m, x, 0.01, 2).g, model, model.initial_state())  # the process's first compile: not timed
    for scene, h in CASES:
        model = getattr(vj.models, scene)()
        x0 = model.initial_state()
        for kind, order in _cases():
            if kind == "forward":
                fn = lambda m, x, o=order, h=h: vj.simulate(m, x, h, FORWARD_STEPS, order=o, throw=False)  # noqa: E731
            else:
                loss = lambda m, x, o=order, h=h: _final_sum(vj.simulate(  # noqa: E731
                    m, x, h, GRADIENT_STEPS, order=o, save_every=GRADIENT_SAVE_EVERY, throw=False))
                fn = lambda m, x, loss=loss: eqx.filter_grad(loss)(m, x)  # noqa: E731
            for plan, patches in PLANS.items():
                jax.clear_caches()  # vj.simulate's inner program is cached by its arguments: trace it anew
                first[(scene, order, kind, plan)], calls[(scene, order, kind, plan)], _ = compiled_under(fn, model, x0, patches=patches)
    seconds = time_alternately(calls, ARGS.repeats)
    rows = []
    for scene, _ in CASES:
        for kind, order in _cases():
            n = FORWARD_STEPS if kind == "forward" else GRADIENT_STEPS
            rolled, unrolled = (seconds[(scene, order, kind, p)] for p in PLANS)
            f_rolled, f_unrolled = (first[(scene, order, kind, p)] for p in PLANS)
            rows.append(dict(scene=scene, order=order, kind=kind, steps=n, rolled_us_per_step=rolled / n * 1e6,
                             unrolled_us_per_step=unrolled / n * 1e6, ratio=rolled / unrolled,
                             rolled_first_call_s=f_rolled, unrolled_first_call_s=f_unrolled))
            print(f"{scene:18s} order {order} {kind:8s}: rolled {rolled / n * 1e6:6.2f} µs/step, unrolled "
                  f"{unrolled / n * 1e6:6.2f} µs/step, ratio {rolled / unrolled:.2f}; first call {f_rolled:5.2f} s / {f_unrolled:5.2f} s")
    write_config_json("rolled_under_jit", ARGS.fast_loops, repeats=ARGS.repeats, rows=rows)


def _cases():
    """(kind, order) of each measurement of a scene."""
    return [("forward", order) for order in FORWARD_ORDERS] + [("gradient", order) for order in GRADIENT_ORDERS]


def _final_sum(sol):
    """A scalar of the final node (position where the scene has one, else the attitude)."""
    return (sol.q[-1] if sol.q is not None else sol.g[-1]).sum()


if __name__ == "__main__":
    main()
