"""Fixed cost of one ``vj.simulate(scheme="splitting")`` call against its cost per step, inside
``jax.jit`` with the scene as an argument (as the work-precision study runs it): at T = 50 s the
fixed part decides the comparison with diffrax (docs/work_precision.md).

Times (compiled code, median and minimum of ``--repeats`` runs; ``--cold``: each run after
touching 64 MB, so that it starts with cold caches, as every program does in the study's
interleaved rounds) for the vehicle at order 6:
the whole call at n = 1 and n = 200 steps with ``throw=False`` (as the study runs it) and
``throw=True`` (the traced separability check as an ``eqx.error_if``), ``separable_parts`` alone (J, M, V by autodiff, the
separability checks, the principal frame), diffrax's Dopri5 at rtol 1e-3 (its whole T = 50 s
solve: the fastest diffrax run at the coarse end of the study), and an empty program on the same
arguments.

    python benchmarks/splitting_overhead.py [--fast-loops] [--repeats 300] [--cold]
"""

import argparse
import sys
import time

from _timing import parse_args_with_fast_loops

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
PARSER.add_argument("--repeats", type=int, default=300)
PARSER.add_argument("--cold", action="store_true", help="evict the caches before every timed run")
ARGS = parse_args_with_fast_loops(PARSER)

import vi_jax as vj  # noqa: E402

import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from vi_jax import continuous  # noqa: E402
from vi_jax.discrete._splitting_pieces import separable_parts  # noqa: E402

jax.config.update("jax_enable_x64", True)


EVICT = np.ones(8_000_000)  # 64 MB, more than the last-level cache


def timed(fn, *args):
    exe = jax.jit(fn).lower(*args).compile()
    jax.block_until_ready(exe(*args))
    samples = []
    for _ in range(ARGS.repeats):
        if ARGS.cold:
            EVICT.sum()
        start = time.perf_counter()
        jax.block_until_ready(exe(*args))
        samples.append(time.perf_counter() - start)
    return 1e3 * float(np.median(samples)), 1e3 * float(np.min(samples))


def main():
    model = vj.models.UnderwaterVehicle()
    x0, h = model.initial_state(), jnp.asarray(0.25)
    rows = {}
    for throw in (False, True):
        for n in (1, 200):
            run = lambda m, x, h, n=n, t=throw: vj.simulate(  # noqa: E731
                m, x, h, n, scheme="splitting", order=6, save_every=n, throw=t
            ).g[-1]
            rows[f"simulate, n = {n}" + (", throw" if throw else "")] = timed(run, model, x0, h)
    rows["separable_parts only"] = timed(lambda m: separable_parts(m).inv_inertia, model)
    y0 = continuous.initial_state(model, x0)
    rows["diffrax Dopri5, rtol 1e-3"] = timed(lambda m, y: diffrax.diffeqsolve(
        continuous.vector_field(m), diffrax.Dopri5(), 0.0, 50.0, None, y,
        stepsize_controller=diffrax.PIDController(rtol=1e-3, atol=1e-3), max_steps=10_000).ys, model, y0)
    rows["empty program"] = timed(lambda m, x, h: x.g * h, model, x0, h)
    print(f"{'XLA loop option' if ARGS.fast_loops else 'XLA default flags'}, vehicle, order 6, "
          f"{'cold' if ARGS.cold else 'warm'} caches ({sys.argv[0]})")
    for label, (median, best) in rows.items():
        print(f"  {label:24s} median {median:.3f} ms   min {best:.3f} ms")
    per_step = (rows["simulate, n = 200"][0] - rows["simulate, n = 1"][0]) / 199
    print(f"  per step ≈ {1e3 * per_step:.2f} µs; fixed ≈ {rows['simulate, n = 1'][0] - per_step:.3f} ms")


if __name__ == "__main__":
    main()
