"""Cost of a DEP step: ``vj.simulate`` on the underwater vehicle (paper's Cayley scheme, 50,000
steps) against a hand-specialised JAX implementation of eq. (88) in the same process.

    python benchmarks/step_cost.py [--steps 50000] [--out benchmarks/results/step_cost.json]
    XLA_FLAGS=--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000 \
        python benchmarks/step_cost.py --out benchmarks/results/step_cost_tuned.json

The second form measures with the XLA:CPU loop option of the command line (vi_jax/engine/_cpu_tuning.py).
The row "blocks of 128 nodes" is the every-node program as it was before ``step_block`` (the
peer that justifies the blocks of 4 nodes of the default loop plan; with the loop option both
rows are the same program). The row "initial state copied in front" is the every-node program
with the initial state concatenated in front of the scanned nodes (the peer of
``_advance._initial_node_in_scan``, the loop option's one scan whose first node is the initial
state; with default XLA both rows are the same program). The row "small products as dots" is the every-node program with
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
from vi_jax.lie import _small  # noqa: E402
from vi_jax.solvers import CHORD_ITERATIONS, _newton  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _timing import time_compiled, write_json  # noqa: E402
from hand_vehicle import simulate_hand, vehicle_params  # noqa: E402


def _with_traced_save_every(system, x0, h, n_saved, save_every, **options):
    """``vj.simulate``'s looped program with ``save_every`` traced even when it is 1: a node loop
    and a step loop of traced lengths (the peer of ``_every_step_in_blocks``)."""
    count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731
    sol = _simulate._simulate_loop(system, x0, h, count(n_saved), count(save_every), capacity=saved_capacity(n_saved), **options)
    return first_rows(sol, n_saved + 1)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--h", type=float, default=0.01)
    parser.add_argument("--out", default="benchmarks/results/step_cost.json")
    args = parser.parse_args()

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    params = vehicle_params(model)

    # Model and initial data are jit arguments, not closed-over constants (no constant folding).
    hand = jax.jit(lambda p, x: simulate_hand(p, x.g, x.q, x.xi, x.qdot, args.h, args.steps, "cayley", 3))
    rows = {}
    rows["hand-specialised eq. (88), 3 Newton its"] = time_compiled(hand, params, x0)
    for order in (1, 2):
        engine = jax.jit(lambda m, x, order=order: vj.simulate(m, x, args.h, args.steps, order=order, throw=False))
        rows[f"vj.simulate order={order}, every node saved + diagnostics"] = time_compiled(engine, model, x0)
    blocks_of_128 = jax.jit(lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False))
    jax.clear_caches()  # vj.simulate's traced program is cached by its arguments: trace it anew
    with mock.patch.object(_advance, "_node_block", lambda state, save_every: SAVE_BLOCK):
        rows[f"vj.simulate order=1, every node saved + diagnostics, blocks of {SAVE_BLOCK} nodes"] = time_compiled(blocks_of_128, model, x0)
    jax.clear_caches()
    copied = jax.jit(lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False))
    with mock.patch.object(_advance, "_initial_node_in_scan", lambda save_every: False):
        rows["vj.simulate order=1, every node saved + diagnostics, initial state copied in front"] = time_compiled(copied, model, x0)
    jax.clear_caches()
    dots = jax.jit(lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False))
    with mock.patch.object(_small, "_is_small_dot", lambda eqn: False):
        rows["vj.simulate order=1, every node saved + diagnostics, small products as dots"] = time_compiled(dots, model, x0)
    jax.clear_caches()
    eliminated = jax.jit(lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False))
    with mock.patch.object(_newton, "lu_factor", lambda A: A), mock.patch.object(_newton, "lu_solve", _newton.dense_solve):
        rows["vj.simulate order=1, every node saved + diagnostics, Jacobian eliminated at every solve"] = time_compiled(eliminated, model, x0)
    jax.clear_caches()
    every_unknown = jax.jit(lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False))
    with mock.patch.object(_advance, "explicit_unknowns", lambda *args: None):
        rows["vj.simulate order=1, every node saved + diagnostics, Newton on every unknown"] = time_compiled(every_unknown, model, x0)
    jax.clear_caches()
    final = jax.jit(lambda m, x: vj.simulate(m, x, args.h, args.steps, save_every=args.steps, throw=False))
    rows["vj.simulate order=1, final node only"] = time_compiled(final, model, x0)
    # The call users make: concrete inputs, one program per saved-node capacity (traced step counts).
    concrete = lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False)  # noqa: E731
    rows["vj.simulate order=1, concrete call, every node saved + diagnostics"] = time_compiled(concrete, model, x0)
    with mock.patch.object(_simulate, "_simulate_looped", _with_traced_save_every):
        rows["vj.simulate order=1, concrete call, every node saved, traced save_every"] = time_compiled(concrete, model, x0)
    common = lambda m, x: vj.simulate(m, x, args.h, args.steps, throw=False, max_newton_iterations=1 + CHORD_ITERATIONS)  # noqa: E731
    rows["vj.simulate order=1, concrete call, one Newton and two chord steps first"] = time_compiled(common, model, x0)
    start = time.perf_counter()
    jax.block_until_ready(vj.simulate(model, x0, args.h, args.steps + 1, throw=False))
    new_n_steps_s = time.perf_counter() - start
    q_hand = rows["hand-specialised eq. (88), 3 Newton its"][2][1][-1]
    q_engine = rows["vj.simulate order=1, every node saved + diagnostics"][2].q[-1]
    agreement = float(jnp.max(jnp.abs(q_hand - q_engine)))

    reference = rows["hand-specialised eq. (88), 3 Newton its"][1]
    print(f"{'implementation':50s} {'compile+1st [s]':>16s} {'median [s]':>11s} {'ratio':>7s}")
    result = {
        "xla_flags": os.environ.get("XLA_FLAGS", ""), "steps": args.steps, "h": args.h,
        "max |q_hand - q_engine| at T": agreement, "rows": {},
        "concrete call with n_steps + 1 (no recompilation expected) [s]": new_n_steps_s,
    }
    for name, (first, median, _) in rows.items():
        print(f"{name:50s} {first:16.3f} {median:11.4f} {median / reference:7.2f}")
        result["rows"][name] = {"compile_and_first_s": first, "median_s": median, "ratio_to_hand": median / reference}
    print(f"max |q_hand(T) − q_engine(T)| = {agreement:.2e} m")
    print(f"concrete call with n_steps + 1 (same program): {new_n_steps_s:.3f} s")
    write_json(args.out, result)


if __name__ == "__main__":
    main()
