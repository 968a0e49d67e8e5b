"""The saved-node capacity of ``vj.simulate`` on concrete inputs: a minimum of 1024 rows (one
program for every run of up to 1024 saved nodes) against the bare next power of two (one
program per power of two). Per run length: the time of a call that compiles a new capacity,
and the median compiled call with each capacity.

    python benchmarks/capacity.py        # ≈ 1 min; writes benchmarks/results/capacity.json
"""

from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax import _saved_nodes  # noqa: E402

from _timing import time_compiled, write_json  # noqa: E402

N_SAVED = [10, 100, 1000]


def main():
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    default = _saved_nodes.MIN_CAPACITY
    rows = []
    for n in N_SAVED:
        row = dict(n_saved=n)
        for name, minimum in (("power of two", 1), ("minimum 1024", default)):
            _saved_nodes.MIN_CAPACITY = minimum
            run = lambda: vj.simulate(model, x0, 0.01, n, progress=False).q  # noqa: E731
            first, median, _ = time_compiled(run)
            row[name] = dict(capacity=_saved_nodes.saved_capacity(n), first_call_s=first, call_ms=median * 1e3)
        _saved_nodes.MIN_CAPACITY = default
        rows.append(row)
        print(f"{n:5d} saved nodes: " + "; ".join(f"{k}: capacity {v['capacity']}, call {v['call_ms']:.2f} ms" for k, v in row.items() if k != "n_saved"))
    write_json(Path(__file__).resolve().parent / "results" / "capacity.json", dict(scene="UnderwaterVehicle", rows=rows))


if __name__ == "__main__":
    main()
