"""``vj.ensemble`` on concrete inputs takes traced step counts (one program per saved-node
capacity, a power of two): the first call, a call with a new ``n_steps`` (final node saved),
and the compiled run time over ``RUN_STEPS`` steps against the traced path (``eqx.filter_jit``
around the call with the scene and h as arguments: static lengths, a program per ``n_steps``),
for the batched step and the ``vmap`` path (vehicle, order 1, 64
members, final node saved), in one process.

    python benchmarks/ensemble_compile.py [--fast-loops]
"""

import time

from _timing import fast_loops_from_argv, time_compiled, write_config_json

FAST_LOOPS = fast_loops_from_argv()

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402

MEMBERS, H, RUN_STEPS = 64, 0.01, 20_000


def seconds(fn, *args):
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - start


def main():
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(0).normal(size=(MEMBERS, 3)))
    rows = []
    for method in ("batched", "vmap"):
        def looped(m, s, h, n, method=method):
            return vj.ensemble(m, s, h, n, save_every=n, method=method, throw=False).q

        def traced(n, method=method):  # scene and h as arguments, as in the looped program
            return eqx.filter_jit(lambda m, s, h: looped(m, s, h, n))

        row = dict(method=method, members=MEMBERS, run_steps=RUN_STEPS)
        row["looped_first_call_s"] = seconds(looped, model, states, H, 1000)
        row["looped_new_n_steps_call_s"] = seconds(looped, model, states, H, 2000)
        row["traced_first_call_s"] = seconds(traced(1000), model, states, H)
        row["traced_new_n_steps_call_s"] = seconds(traced(2000), model, states, H)
        row["looped_run_s"] = time_compiled(lambda *a: looped(*a, RUN_STEPS), model, states, H, repeats=7)[1]
        row["traced_run_s"] = time_compiled(traced(RUN_STEPS), model, states, H, repeats=7)[1]
        row["looped_over_traced"] = row["looped_run_s"] / row["traced_run_s"]
        rows.append(row)
        print(", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    write_config_json("ensemble_compile", FAST_LOOPS, rows=rows)


if __name__ == "__main__":
    main()
