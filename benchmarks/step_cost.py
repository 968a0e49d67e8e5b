"""Cost of a DEP step: ``vj.simulate`` on the underwater vehicle (paper's Cayley scheme, 50,000
steps) against a hand-specialised JAX implementation of eq. (88) in the same process.

    python benchmarks/step_cost.py [--steps 50000] [--out benchmarks/results/step_cost.json]
    XLA_FLAGS=--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000 \
        python benchmarks/step_cost.py --out benchmarks/results/step_cost_tuned.json

The second form measures with the XLA:CPU loop option of the command line (vi_jax/engine/_cpu_tuning.py).
The row "hand-specialised eq. (88) + node diagnostics by hand" is the like-for-like peer of
``vj.simulate``'s every-node rows: the hand-written steps followed by the nodes' velocities,
energy, Kelvin–Noether quantity and its scale written out by hand
(tests/hand_vehicle.py ``node_diagnostics_hand``); each row's ``ratio_to_hand_with_diagnostics``
is against it, ``ratio_to_hand`` against the steps alone. The rows are timed alternately
(``--repeats`` times each); beside the medians' ratios, the minima's (``min_ratio_to_hand*``):
this 2-core machine switches between speeds ~1.6× apart within one process, and a row's minimum
is its time in the faster one.
The row "blocks of 128 nodes" is the every-node program as it was before ``step_block`` (the
peer that justifies the blocks of 4 nodes of the default loop plan; with the loop option both
rows are the same program). The row "initial state copied in front" is the every-node program
with the initial state concatenated in front of the scanned nodes (the peer of
``_advance._initial_node_in_scan``: where the loops are one kernel, with the loop option or as
a region with default XLA, the nodes are one scan whose first node is the initial state). The row "small products as dots" is the every-node program with
the products of the Lagrangian left as ``dot_general``s (the peer of ``fused_products``,
``vi_jax/lie/_small.py``). The row "Jacobian eliminated at every solve" is the every-node
program with Newton's solves by ``dense_solve`` instead of factors computed once (the peer of
``lu_factor``, ``vi_jax/solvers/_newton.py``); the row "Newton on every unknown" is the
every-node program with Newton on (ω, ν) instead of ν solved first from its explicit equations
(eq. 74; the peer of ``vi_jax/engine/_explicit_unknowns.py``); the row "one Newton and two chord steps first"
is the concrete call's program without Newton's full iterations, which ``vj.simulate`` ran
first before its Jacobian was factored once (``vj.ensemble``'s generated step still does); the
row "traced save_every" is the concrete call's program with a node loop and a step loop of
traced lengths, which ``vj.simulate`` ran before every-step runs got blocks of steps.
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from unittest import mock

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax._saved_nodes import SAVE_BLOCK, first_rows, saved_capacity  # noqa: E402
from vi_jax.engine import _advance, _simulate  # noqa: E402
from vi_jax.engine._compile_options import single_trajectory_jit  # noqa: E402
from vi_jax.lie import _small  # noqa: E402
from vi_jax.solvers import CHORD_ITERATIONS, _newton  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _timing import alternate_samples, compiled_under, under_patches, write_json  # noqa: E402
from hand_vehicle import node_diagnostics_hand, simulate_hand, vehicle_params  # noqa: E402


# The concrete call's loop and node diagnostics as one program (vj.simulate runs them as two).
_LOOP_PROGRAM = single_trajectory_jit(_simulate.loop_program)
HAND = "hand-specialised eq. (88), 3 Newton its"
WITH_DIAGNOSTICS = "hand-specialised eq. (88) + node diagnostics by hand"


def _with_traced_save_every(system, x0, h, n_saved, save_every, **options):
    """``vj.simulate``'s looped program with ``save_every`` traced even when it is 1: a node loop
    and a step loop of traced lengths (the peer of ``_every_step_in_blocks``)."""
    count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731
    sol = _LOOP_PROGRAM(system, x0, h, count(n_saved), count(save_every), capacity=saved_capacity(n_saved), **options)
    return first_rows(sol, n_saved + 1)


def _concrete(fn, *args, patches=()):
    """A concrete call of ``fn`` (its programs cached by vi_jax), made under ``patches`` every
    time: (first call seconds, a call, its output)."""

    def call():
        with under_patches(patches):
            return fn(*args)

    start = time.perf_counter()
    out = jax.block_until_ready(call())
    return time.perf_counter() - start, call, out


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--h", type=float, default=0.01)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--out", default="benchmarks/results/step_cost.json")
    args = parser.parse_args()

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    params = vehicle_params(model)
    n, h = args.steps, args.h

    # Model and initial data are jit arguments, not closed-over constants (no constant folding).
    hand = lambda p, x: simulate_hand(p, x.g, x.q, x.xi, x.qdot, h, n, "cayley", 3)  # noqa: E731
    every = lambda m, x: vj.simulate(m, x, h, n, throw=False)  # noqa: E731
    every_row = "vj.simulate order=1, every node saved + diagnostics"
    rows = {HAND: compiled_under(hand, params, x0)}
    rows[WITH_DIAGNOSTICS] = compiled_under(lambda p, x: (nodes := hand(p, x)) + node_diagnostics_hand(p, *nodes), params, x0)
    for order in (1, 2):
        rows[f"vj.simulate order={order}, every node saved + diagnostics"] = compiled_under(
            lambda m, x, order=order: vj.simulate(m, x, h, n, order=order, throw=False), model, x0
        )
    variants = {
        f"blocks of {SAVE_BLOCK} nodes": (mock.patch.object(_advance, "_node_block", lambda state, save_every: SAVE_BLOCK),),
        "initial state copied in front": (mock.patch.object(_advance, "_initial_node_in_scan", lambda save_every: False),),
        "small products as dots": (mock.patch.object(_small, "_is_small_dot", lambda eqn: False),),
        "Jacobian eliminated at every solve": (mock.patch.object(_newton, "lu_factor", lambda A: A),
                                               mock.patch.object(_newton, "lu_solve", _newton.dense_solve)),
        "Newton on every unknown": (mock.patch.object(_advance, "explicit_unknowns", lambda *args: None),),
    }
    for name, patches in variants.items():
        jax.clear_caches()  # vj.simulate's traced program is cached by its arguments: trace it anew
        rows[f"{every_row}, {name}"] = compiled_under(every, model, x0, patches=patches)
    rows["vj.simulate order=1, final node only"] = compiled_under(lambda m, x: vj.simulate(m, x, h, n, save_every=n, throw=False), model, x0)
    # The call users make: concrete inputs, one program per saved-node capacity (traced step counts).
    rows["vj.simulate order=1, concrete call, every node saved + diagnostics"] = _concrete(every, model, x0)
    rows["vj.simulate order=1, concrete call, every node saved, traced save_every"] = _concrete(
        every, model, x0, patches=(mock.patch.object(_simulate, "_simulate_looped", _with_traced_save_every),)
    )
    rows["vj.simulate order=1, concrete call, one Newton and two chord steps first"] = _concrete(
        lambda m, x: vj.simulate(m, x, h, n, throw=False, max_newton_iterations=1 + CHORD_ITERATIONS), model, x0
    )
    start = time.perf_counter()
    jax.block_until_ready(vj.simulate(model, x0, h, n + 1, throw=False))
    new_n_steps_s = time.perf_counter() - start
    agreement = float(jnp.max(jnp.abs(rows[HAND][2][1][-1] - rows[every_row][2].q[-1])))

    samples = alternate_samples({name: call for name, (_, call, _) in rows.items()}, repeats=args.repeats)
    medians = {name: statistics.median(s) for name, s in samples.items()}
    minima = {name: min(s) for name, s in samples.items()}
    reference, like_for_like = medians[HAND], medians[WITH_DIAGNOSTICS]
    print(f"{'implementation':50s} {'compile+1st [s]':>16s} {'median [s]':>11s} {'ratio':>7s} {'ratio to hand + diagnostics':>28s} {'same by minima':>15s}")
    result = {
        "xla_flags": os.environ.get("XLA_FLAGS", ""), "steps": n, "h": h, "repeats_alternately": args.repeats,
        "max |q_hand - q_engine| at T": agreement, "rows": {},
        "concrete call with n_steps + 1 (no recompilation expected) [s]": new_n_steps_s,
    }
    for name, (first, _, _) in rows.items():
        median, by_minima = medians[name], minima[name] / minima[WITH_DIAGNOSTICS]
        print(f"{name:50s} {first:16.3f} {median:11.4f} {median / reference:7.2f} {median / like_for_like:28.2f} {by_minima:15.2f}")
        result["rows"][name] = {"compile_and_first_s": first, "median_s": median, "ratio_to_hand": median / reference,
                                "ratio_to_hand_with_diagnostics": median / like_for_like, "min_s": minima[name],
                                "min_ratio_to_hand": minima[name] / minima[HAND], "min_ratio_to_hand_with_diagnostics": by_minima}
    print(f"max |q_hand(T) − q_engine(T)| = {agreement:.2e} m")
    print(f"concrete call with n_steps + 1 (same program): {new_n_steps_s:.3f} s")
    write_json(args.out, result)

if __name__ == "__main__":
    main()
