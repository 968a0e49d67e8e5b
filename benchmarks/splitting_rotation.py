"""Cost per step of the splitting's rotation flows, three formulations side by side in one
process: it decides how ``vi_jax.discrete._splitting_pieces.rotate`` is written.

- ``three products, jnp trig``: g', Π' and P' each turned by its own small product, cos θ − 1
  and sin θ by half-angle ``jnp.sin``/``jnp.cos`` (the formulation before);
- ``one product, jnp trig``: on SO(3) the rows of g', Π'ᵀ and P'ᵀ turned by one product;
- ``one product, polynomial``: the same with |θ| ≤ 1 taking the Taylor polynomials behind a
  ``lax.cond`` (``_cos_minus_one_sin`` under the loop option);
- ``columns, …``: the rows turned column by column (two updated columns stacked with the third)
  rather than by a product;
- ``library``: ``rotate`` as shipped (the plan it picks for this XLA configuration).

Every formulation applies the rotation as an increment, v + ((c − 1)v + s w) (see
``_splitting_pieces``: a rotation by the same angle at every step must not rescale g); the
pieces are the planar rotations about the three principal axes (no sphere piece).

Vehicle and heavy top, order 6 (Blanes–Moan, 10 stages), h = 0.25 / 0.02; per step = (time of
2,000 steps − time of 20 steps) / 1,980, compiled code, median of ``--repeats``.

    python benchmarks/splitting_rotation.py [--fast-loops] [--repeats 30]
"""

import argparse
import time

from _timing import parse_args_with_fast_loops, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--repeats", type=int, default=30)
ARGS = parse_args_with_fast_loops(PARSER)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax.discrete import _splitting as S  # noqa: E402
from vi_jax.discrete import _splitting_pieces as sp  # noqa: E402

jax.config.update("jax_enable_x64", True)


def _trig(theta):
    return sp._cos_minus_one_sin_trig(theta)


def _polynomial(theta):
    return sp._cos_minus_one_sin(theta, loop_option=True)


def three_products(parts, k, t, s):
    cm1, sn = _trig(t * (s.Pi[k] * parts.inv_inertia[k]))
    i, j = parts.planes[k]
    Dt = sp._planar_increment(cm1, sn, ((i, j, 1.0),), s.g.shape[-1])
    P = None if s.P is None else s.P + sp.matvec(Dt, s.P)
    Pi = s.Pi + sp.matvec(sp._planar_increment(cm1, sn, parts.pairs[k], 3), s.Pi)
    return sp.Phase(s.g + sp.matmul(s.g, Dt.T), s.q, Pi, P)


def rows_turned(cos_sin, by_columns=False):
    def rotate(parts, k, t, s):
        cm1, sn = cos_sin(t * (s.Pi[k] * parts.inv_inertia[k]))
        i, j = parts.planes[k]
        rows = jnp.concatenate([s.g, s.Pi[None]] + ([] if s.P is None else [s.P[None]]))
        if by_columns:
            rows = sp._turn_columns(rows, i, j, cm1, sn)
        else:
            rows = rows + sp.matmul(rows, sp._planar_increment(cm1, sn, ((i, j, 1.0),), 3).T)
        return sp.Phase(rows[:3], s.q, rows[3], None if s.P is None else rows[4])

    return rotate


VARIANTS = {
    "three products, jnp trig": three_products,
    "one product, jnp trig": rows_turned(_trig),
    "one product, polynomial": rows_turned(_polynomial),
    "columns, jnp trig": rows_turned(_trig, by_columns=True),
    "columns, polynomial": rows_turned(_polynomial, by_columns=True),
    "library": sp.rotate,
}


def per_step(model, h, rotate):
    parts = sp.separable_parts(model)
    phase = S.initial_phase(parts, model.initial_state())
    table = S.stage_table(S.DEFAULTS[6][0])

    def run(parts, phase, h, n):
        flows = sp.piece_flows(parts)
        for k in range(3):
            flows[k] = lambda t, s, k=k: rotate(parts, k, t, s)
        pieces = S.arrange(tuple(flows), S.DEFAULTS[6][1])
        return S._steps(flows, pieces, table, h, phase, n)

    times, outs = [], []
    for n in (20, 2000):
        exe = jax.jit(run, static_argnums=3).lower(parts, phase, h, n).compile()
        outs.append(jax.block_until_ready(exe(parts, phase, h)))
        samples = []
        for _ in range(ARGS.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(exe(parts, phase, h))
            samples.append(time.perf_counter() - t0)
        times.append(float(np.median(samples)))
    return 1e6 * (times[1] - times[0]) / 1980, outs[1]


def main():
    config = "loop option" if ARGS.fast_loops else "XLA default flags"
    rows = {}
    for name, model, h in (("vehicle", vj.models.UnderwaterVehicle(), 0.25), ("heavy top", vj.models.HeavyTop(), 0.02)):
        reference = None
        for label, rotate in VARIANTS.items():
            us, out = per_step(model, jnp.asarray(h), rotate)
            reference = out.g if reference is None else reference
            diff = float(jnp.max(jnp.abs(out.g - reference)))
            rows[f"{name}: {label}"] = dict(us_per_step=us, max_g_difference=diff)
            print(f"{config:18s} {name:10s} {label:26s} {us:6.3f} µs/step   |Δg| vs first {diff:.1e}")
    write_config_json("splitting_rotation", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
