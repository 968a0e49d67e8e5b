"""The generated step with the scene's exact zeros folded (``FOLD_ZEROS``,
``vi_jax/engine/_ensemble.py``; ``zero_entries``, ``vi_jax/engine/_generated_step.py``) against
the same step with every parameter entry a traced value: ``vj.ensemble`` called on concrete
inputs as users call it, and under a ``jit`` that closes over the scene (1024 members × 1000
steps, final node saved, Cayley, h = 0.01), the four programs compiled in one process and timed
alternately (median and fastest of 9 runs each; the first calls: the concrete calls', unfolded first),
with the operations per member of the residual and of the residual with its Jacobian
(the jaxprs' member-array equations) either way. The scenes' matrices are diagonal (inertia,
added mass) and their offsets have zero components: a product with such an entry folds away
at trace time, as the zeros of structure matrices do. "mass per member": every parameter leaf
carries the member axis (``vj.vary``), zero for every member.

    python benchmarks/folded_zeros.py [--fast-loops]
"""

import argparse

from _timing import alternate_samples, parse_args_with_fast_loops, write_config_json

PARSER = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ARGS = parse_args_with_fast_loops(PARSER)

import statistics  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax.engine import _ensemble, _generated_step  # noqa: E402

MEMBERS, STEPS, REPEATS, H = 1024, 1000, 9, 0.01
CASES = [("rigid_body", vj.models.RigidBody, 1), ("rigid_body", vj.models.RigidBody, 2), ("heavy_top", vj.models.HeavyTop, 1),
         ("heavy_top", vj.models.HeavyTop, 2), ("vehicle", vj.models.UnderwaterVehicle, 1), ("vehicle", vj.models.UnderwaterVehicle, 2),
         ("vehicle, mass per member", vj.models.UnderwaterVehicle, 1)]


def calls(model, system_axes, states, order):
    """Per variant (folded or not): the concrete call, and the run under a ``jit`` that closes over
    the scene, compiled ahead of time with the switch set (it is read when the step is traced)."""
    def ensemble(states):
        return vj.ensemble(model, states, H, STEPS, order=order, save_every=STEPS, system_axes=system_axes, throw=False).g

    def concrete(folded):
        def run():
            _ensemble.FOLD_ZEROS = folded
            return ensemble(states)

        return run

    def closed_over(folded):
        _ensemble.FOLD_ZEROS = folded
        jax.clear_caches()  # else jit reuses the other variant's trace
        compiled = jax.jit(ensemble).lower(states).compile()
        return lambda: compiled(states)

    return {(kind, folded): make(folded) for kind, make in (("concrete", concrete), ("closed over", closed_over)) for folded in (False, True)}


def main():
    rows = []
    try:
        for name, scene, order in CASES:
            model, system_axes = scene(), None
            if "per member" in name:
                model, system_axes = vj.vary(model, mass=model.mass * np.linspace(0.98, 1.02, MEMBERS)), 0
            states = perturbed_states(scene().initial_state(), MEMBERS)
            runs = calls(model, system_axes, states, order)
            first, finals = {}, {}
            for key in [k for k in runs if k[0] == "concrete"]:
                start = time.perf_counter()
                finals[key[1]] = np.asarray(jax.block_until_ready(runs[key]())[:, -1])
                first[key[1]] = time.perf_counter() - start
            samples = alternate_samples(runs, REPEATS)
            rate = {k: MEMBERS * STEPS / statistics.median(s) for k, s in samples.items()}
            fastest = {k: MEMBERS * STEPS / min(s) for k, s in samples.items()}
            ops = {f: _generated_step.scene_operations(model, states, H, order=order, system_axes=system_axes, folded=f) for f in (False, True)}
            diff = float(np.max(np.abs(finals[True] - finals[False])))
            speedup = {kind: rate[kind, True] / rate[kind, False] for kind in ("concrete", "closed over")}
            rows.append(dict(scene=name, order=order, operations_traced=ops[False], operations_folded=ops[True],
                             traced_rate=rate["concrete", False], folded_rate=rate["concrete", True], speedup=speedup["concrete"],
                             speedup_fastest=fastest["concrete", True] / fastest["concrete", False],
                             closed_over_traced_rate=rate["closed over", False], closed_over_folded_rate=rate["closed over", True],
                             closed_over_speedup=speedup["closed over"], first_call_traced_s=first[False],
                             first_call_folded_s=first[True], max_abs_g_difference=diff))
            print(f"{name:24s} order {order}: operations {ops[False]} -> {ops[True]}; concrete {rate['concrete', False] / 1e6:6.2f} -> "
                  f"{rate['concrete', True] / 1e6:6.2f} M member-steps/s ({speedup['concrete']:.2f}x by medians, "
                  f"{fastest['concrete', True] / fastest['concrete', False]:.2f}x by the fastest); under a jit closing over the scene "
                  f"{rate['closed over', False] / 1e6:6.2f} -> {rate['closed over', True] / 1e6:6.2f} M ({speedup['closed over']:.2f}x); "
                  f"first call {first[False]:.1f} / {first[True]:.1f} s; max |g difference| {diff:.1e}", flush=True)
    finally:
        _ensemble.FOLD_ZEROS = True
    write_config_json("folded_zeros", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
