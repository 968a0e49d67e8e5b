"""Why vi_jax writes small matrix products as broadcast-multiply-sum (``vi_jax/lie/_small.py``),
and what the XLA:CPU while-loop option does to a step.

Times, in one process per XLA configuration (compiled code only, median of 7):

- the Newton Jacobian of a Cayley-rotated quadratic form x ↦ cay(x)ᵀA cay(x)v (the shape of
  the trapezoid rule's second Lagrangian evaluation) inside a 4000-step ``lax.scan``, written
  with ``@`` against ``_small.matmul``/``matvec``, alone and under ``jax.vmap`` over 1024
  members (per member-step);
- a whole ``vj.simulate`` step of the underwater vehicle (Cayley, h = 0.01, final state only)
  for orders 1, 2 and 4.

Configurations: ``default`` (no XLA flags) and ``tuned``, XLA_FLAGS
``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000`` (XLA:CPU
compiles a whole while loop into one kernel instead of dispatching each operation).

    python benchmarks/small_products.py [--out benchmarks/results/small_products.json]
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

HERE = Path(__file__).resolve().parent
N_STEPS = 4000


def measure():
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    import vi_jax as vj
    from vi_jax.lie._small import matmul, matvec
    from vi_jax.lie._so3 import skew3

    sys.path.insert(0, str(HERE))
    from _timing import time_compiled

    A = jnp.diag(jnp.array([1.0, 2.0, 3.0]))
    v = jnp.array([0.3, -0.2, 0.5])
    eye = jnp.eye(3)

    def with_dots(x):
        X = skew3(x)
        R = eye + (4 / (4 + x @ x)) * (X + 0.5 * X @ X)
        return R.T @ (A @ (R @ v))

    def fused(x):
        X = skew3(x)
        R = eye + (4 / (4 + jnp.sum(x * x))) * (X + 0.5 * matmul(X, X))
        return matvec(R.T, matvec(A, matvec(R, v)))

    rows = []
    for name, fn in (("Jacobian, @", with_dots), ("Jacobian, fused", fused)):
        scan = jax.jit(lambda x, fn=fn: jax.lax.scan(lambda c, _: (c + 1e-9 * jax.jacfwd(fn)(c)[0], None), x, None, length=N_STEPS)[0])
        _, median, _ = time_compiled(scan, jnp.array([0.1, 0.2, 0.3]))
        rows.append(dict(case=name, us_per_step=median / N_STEPS * 1e6))
    for name, fn in (("Jacobian, @, vmap 1024", with_dots), ("Jacobian, fused, vmap 1024", fused)):
        step = jax.vmap(lambda c, fn=fn: c + 1e-9 * jax.jacfwd(fn)(c)[0])
        scan = jax.jit(lambda x, step=step: jax.lax.scan(lambda c, _: (step(c), None), x, None, length=N_STEPS // 20)[0])
        _, median, _ = time_compiled(scan, jnp.tile(jnp.array([0.1, 0.2, 0.3]), (1024, 1)))
        rows.append(dict(case=name, us_per_step=median / (N_STEPS // 20) / 1024 * 1e6))
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    for order in (1, 2, 4):
        run = jax.jit(lambda m, x, h, order=order: vj.simulate(m, x, h, N_STEPS, order=order, save_every=N_STEPS, throw=False).q[-1])
        _, median, _ = time_compiled(run, model, x0, 0.01)
        rows.append(dict(case=f"vj.simulate order {order}", us_per_step=median / N_STEPS * 1e6))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE / "results" / "small_products.json")
    args = parser.parse_args()
    results = {}
    for config, flags in (("default", ""), ("tuned", FAST_LOOPS_FLAG)):
        env = dict(os.environ, XLA_FLAGS=flags)
        out = subprocess.run([sys.executable, __file__, "--worker"], env=env, check=True, capture_output=True, text=True)
        results[config] = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"{'case':28s} {'default µs':>11s} {'tuned µs':>9s}")
    for d, t in zip(results["default"], results["tuned"]):
        print(f"{d['case']:28s} {d['us_per_step']:11.2f} {t['us_per_step']:9.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(dict(flags={"default": "", "tuned": FAST_LOOPS_FLAG}, rows=results), indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    if "--worker" in sys.argv:
        print(json.dumps(measure()))
    else:
        main()
