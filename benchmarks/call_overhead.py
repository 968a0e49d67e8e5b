"""Fixed cost of a concrete ``vj.simulate`` call (the host work around its compiled program)
and its cost per step, from the medians at two run lengths.

    python benchmarks/call_overhead.py [--fast-loops]

Vehicle, h = 0.01, float64, a node every step or every 10 steps; the DEP scheme (order 1) and
Strang's splitting. Peer row: the splitting with the group's static axes recomputed at every call
(``separable_parts``'s ``_axes`` without its cache, as before it was kept per group), timed in
the same process, alternately.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import parse_args_with_fast_loops, time_alternately, write_config_json  # noqa: E402

LENGTHS = (5000, 20000)


def main():
    args = parse_args_with_fast_loops()
    import jax

    jax.config.update("jax_enable_x64", True)
    import vi_jax as vj
    from vi_jax.discrete import _splitting_pieces

    cached = _splitting_pieces._axes
    uncached = cached.__wrapped__
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()

    def call(scheme, save_every, n, axes):
        def run():
            _splitting_pieces._axes = axes
            try:
                return vj.simulate(model, x0, 0.01, n, scheme=scheme, save_every=save_every, throw=False).g
            finally:
                _splitting_pieces._axes = cached

        return run

    peers = {
        (f"{scheme}, {label}", save_every, n): call(scheme, save_every, n, axes)
        for scheme, label, axes in (("dep", "", cached), ("splitting", "axes cached", cached), ("splitting", "axes recomputed (before)", uncached))
        for save_every in (1, 10)
        for n in LENGTHS
    }
    for run in peers.values():  # compile
        jax.block_until_ready(run())
    times = time_alternately(peers)
    rows = []
    short, long = LENGTHS
    for name, save_every in {(k[0], k[1]) for k in peers}:
        t_short, t_long = times[(name, save_every, short)], times[(name, save_every, long)]
        per_step = (t_long - t_short) / (long - short)
        fixed = t_short - short * per_step
        rows.append(dict(peer=name.rstrip(", "), save_every=save_every, fixed_ms=1e3 * fixed, us_per_step=1e6 * per_step))
    rows.sort(key=lambda r: (r["peer"], r["save_every"]))
    for r in rows:
        print(f"{r['peer']:38s} every {r['save_every']:3d}: fixed {r['fixed_ms']:6.2f} ms, {r['us_per_step']:5.2f} µs/step")
    write_config_json("call_overhead", args.fast_loops, jax=jax.__version__, lengths=LENGTHS, rows=rows)


if __name__ == "__main__":
    main()
