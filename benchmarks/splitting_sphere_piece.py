"""The splitting's arrangements with and without the sphere piece, which decides the defaults of
``vi_jax.discrete._splitting.DEFAULTS``: the rotational kinetic energy split as
½|Π|²/I₁ + Σ_{k=0,2} ½(1/I_k − 1/I₁)Π_k² (I₁ the middle moment; Π fixed, g and P turned about
Π) instead of one planar rotation per principal axis. The sphere piece commutes with the
rotations about the other axes, so for a symmetric body the free motion is exact.

For each order's default method: the final-state error at T = 50 s (max over R(T) and q(T)/|q|
against Dopri8 at rtol = atol = 1e-13) at three steps, and the cost per step (time of 2,000
steps − time of 20 steps, / 1,980; compiled code, median of ``--repeats``), vehicle and heavy
top, the default arrangement (sphere piece) against the same without it.

    python benchmarks/splitting_sphere_piece.py [--fast-loops] [--repeats 15]
"""

import argparse

from _timing import parse_args_with_fast_loops, time_compiled, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--repeats", type=int, default=15)
ARGS = parse_args_with_fast_loops(PARSER)

import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax import continuous  # noqa: E402
from vi_jax.discrete import _splitting as S  # noqa: E402

jax.config.update("jax_enable_x64", True)

T = 50.0
CASES = {  # scene, steps h per order
    "vehicle": (vj.models.UnderwaterVehicle(), {2: (0.1, 0.05, 0.025), 4: (1.0, 0.5, 0.25), 6: (1.0, 0.5, 0.25), 8: (1.0, 0.5, 0.25)}),
    "heavy top": (vj.models.HeavyTop(), {2: (0.02, 0.01, 0.005), 4: (0.25, 0.125, 0.0625), 6: (0.25, 0.125, 0.0625), 8: (0.25, 0.125, 0.0625)}),
}


def reference(model):
    y0 = continuous.initial_state(model, model.initial_state())
    sol = diffrax.diffeqsolve(continuous.vector_field(model), diffrax.Dopri8(), 0.0, T, None, y0,
                              stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-13), max_steps=10**7)
    return sol.ys[0][-1], None if sol.ys[2] is None else sol.ys[2][-1]


def program(order, arrangement, n):
    return jax.jit(lambda m, x, h: S.splitting_run(m, x, h, n, order, save_every=n, arrangement=arrangement))


def final_error(model, order, arrangement, h, ref):
    n = round(T / h)
    out = program(order, arrangement, n)(model, model.initial_state(), jnp.asarray(h))
    err = float(jnp.max(jnp.abs(out.g[-1] - ref[0])))
    if ref[1] is not None:
        err = max(err, float(jnp.max(jnp.abs(out.q[-1] - ref[1])) / jnp.max(jnp.abs(ref[1]))))
    return err


def us_per_step(model, order, arrangement, h):
    args = (model, model.initial_state(), jnp.asarray(h))
    long, short = (time_compiled(program(order, arrangement, n), *args, repeats=ARGS.repeats)[1] for n in (2000, 20))
    return 1e6 * (long - short) / 1980


def main():
    rows = []
    for name, (model, steps) in CASES.items():
        ref = reference(model)
        for order in S.ORDERS:
            row = {"system": name, "order": order, "method": S.resolve(order)[0], "h": list(steps[order])}
            for label, sphere in (("sphere", True), ("planar", False)):
                arrangement = S.resolve(order, sphere=sphere)[1]
                row[label] = {
                    "arrangement": [str(p) for p in arrangement],
                    "errors": [final_error(model, order, arrangement, h, ref) for h in steps[order]],
                    "us_per_step": us_per_step(model, order, arrangement, steps[order][-1]),
                }
            ratio = np.asarray(row["planar"]["errors"]) / np.asarray(row["sphere"]["errors"])
            cost = row["sphere"]["us_per_step"] / row["planar"]["us_per_step"]
            # At equal error, time ∝ cost per step × steps ∝ cost × (error ratio)^(−1/order).
            row["time_ratio_at_equal_error"] = [float(cost * r ** (-1 / order)) for r in ratio]
            rows.append(row)
            print(f"{name:9s} order {order} ({row['method']}): error planar/sphere "
                  + " ".join(f"{r:9.3g}" for r in ratio)
                  + f"   µs/step {row['sphere']['us_per_step']:.2f} vs {row['planar']['us_per_step']:.2f}"
                  + "   time sphere/planar at equal error " + " ".join(f"{t:.2f}" for t in row["time_ratio_at_equal_error"]),
                  flush=True)
    write_config_json("splitting_sphere_piece", ARGS.fast_loops, T=T, rows=rows)


if __name__ == "__main__":
    main()
