"""Ensemble throughput on an accelerator (issue: "GPU figures"), and where a single trajectory
should run. Meant for a GPU machine; runs anywhere (small sizes on a CPU as a smoke test).

    python benchmarks/ensemble_gpu.py [--members 1024 32768 1048576] [--dtypes float64 float32]
        [--cases vehicle1 vehicle1_hand heavy_top2 heavy_top1 vehicle2] [--budget-s 520] [--out FILE]
        [--extrapolation]

Rows, written to ``--out`` after every measurement (so a run cut short keeps what it measured):

- ``ensemble``: ``jax.jit`` of ``vj.ensemble`` (``method="auto"``: the step generated from the
  scene; ``vehicle1_hand`` is the vehicle at order 1 through the hand-written batched step of
  ``_hand_vehicle_kernel.py``, the peer), member-steps per second, the final
  node only saved and only small outputs returned (final ξ, converged fraction), h = 0.01 (vehicle) / 0.005 (heavy top), Cayley, members with perturbed
  initial velocities. Each size runs ``min(1000, 2.5e8 / members)`` steps (the rate is per
  member-step), compiled code only, median of 5; with the most Newton iterations any member took
  in a step (above 3: Newton's fallback ran, on a GPU for the whole batch).
- ``peers`` (vehicle order 1, float64, ``--peer-members``): a plain ``jax.vmap`` of the hand-written
  step (tests/hand_vehicle.py), and ``vj.ensemble`` with the CPU plan (chunks of 64 members
  one after another, what every backend ran before) at no more than ``CPU_PLAN_MEMBERS`` members
  (its chunks run one after another: at 32,768 members its timing alone outran a 600 s call).
- ``peers`` (every generated case, float64, ``--peer-members``): ``method="vmap"``, a plain
  ``jax.vmap`` of ``vj.simulate``'s program.
- ``--extrapolation``: the generated step starts Newton from 2ξ_k − ξ_{k−1} instead of ξ_k
  (``_generated_step.PREDICT_ON_ACCELERATORS``; the accelerator plan's default since the
  speculative step, ``gpu_step_profile.py``), rows marked ``extrapolated_guess``. Rows of earlier
  runs: ``extrapolated_guess: false`` marks a run of the old ``--no-extrapolation``; unmarked rows
  of those runs started from the extrapolation, as the plan then did.
- ``agreement``: per case and dtype, the first 4 members' final states against ``vj.simulate``
  on the host CPU in float64 (max abs difference of R and ξ).
- ``single`` (before the peers): one trajectory, ``vj.simulate`` of the vehicle at order 1, µs per step on the
  default device, and on the host CPU with default XLA flags and with the loop option (child
  processes: XLA reads its flags once).
"""

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _timing import time_compiled  # noqa: E402
CASES = {"vehicle1": ("vehicle", 1), "vehicle1_hand": ("vehicle", 1), "vehicle2": ("vehicle", 2),
         "heavy_top1": ("heavy_top", 1), "heavy_top2": ("heavy_top", 2)}
STEP = {"vehicle": 0.01, "heavy_top": 0.005}
CPU_PLAN_MEMBERS = 4096


def _cast(tree, dtype):
    """Every floating array of ``tree`` in ``dtype``."""
    import jax
    import jax.numpy as jnp

    return jax.tree.map(lambda x: jnp.asarray(x, dtype) if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def _scene(name, dtype):
    import vi_jax as vj

    model = vj.models.UnderwaterVehicle() if name == "vehicle" else vj.models.HeavyTop()
    return _cast(model, dtype), _cast(model.initial_state(), dtype)


@contextlib.contextmanager
def _fusion_boundaries(on):
    """With ``on``, the generated step keeps its fusion boundaries on every backend (the CPU
    plan's; by default a GPU plan runs without them); the plan's other choices stay the
    backend's. ``make_step``'s ninth argument is ``boundaries`` (after it: ``carry_factors``)."""
    from vi_jax.engine import _generated_step

    real = _generated_step.make_step
    if on:
        _generated_step.make_step = lambda *args: real(*args[:8], True, *args[9:])
    try:
        yield
    finally:
        _generated_step.make_step = real


def _summary(sol):
    """What a timed run returns: every member's final ξ, the fraction of members whose Newton
    solves all converged, the most Newton iterations any member took in a step (above 3: the
    fallback ran, for the whole batch on a GPU), and the first 4 members' final R and ξ (small
    outputs only)."""
    import jax.numpy as jnp

    from vi_jax.engine._ensemble import member_converged

    return sol.xi[:, -1], jnp.mean(member_converged(sol)), jnp.max(sol.newton_iterations), sol.g[:4, -1], sol.xi[:4, -1]


def _member(states, k):
    """Member ``k`` of a batched state, in float64 on the host."""
    import jax
    import numpy as np

    return jax.tree.map(lambda x: np.asarray(x[k], np.float64), states)


def _states(x0, members, dtype):
    """``members`` initial states: x0 with ξ perturbed by 0.05·N(0, 1) per component."""
    import jax.numpy as jnp
    import numpy as np

    from vi_jax.engine._ensemble import vary

    omegas = np.asarray(x0.xi, np.float64) + 0.05 * np.random.default_rng(0).normal(size=(members, 3))
    return vary(x0, xi=jnp.asarray(omegas, dtype))


def measure(args):
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import vi_jax as vj
    from vi_jax.engine import _ensemble
    from _hand_vehicle_kernel import hand_kernel_ensemble

    sys.path.insert(0, str(HERE.parent / "tests"))
    from hand_vehicle import make_step, vehicle_params

    out = dict(device=str(jax.devices()[0]), backend=jax.default_backend(), jax=jax.__version__, rows=[])
    if args.extrapolation:
        from vi_jax.engine import _generated_step

        _generated_step.PREDICT_ON_ACCELERATORS = True
    start = time.perf_counter()

    def save():
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=2))

    def over_budget():
        return time.perf_counter() - start > args.budget_s

    def final(model, h, n_steps, method="auto"):
        return jax.jit(lambda x: _ensemble.ensemble(model, x, h, n_steps, save_every=n_steps, method=method, throw=False).xi[:, -1])

    for case in args.cases:
        name, order = CASES[case]
        for dtype_name in args.dtypes:
            dtype = jnp.dtype(dtype_name)
            model, x0 = _scene(name, dtype)
            h = jnp.asarray(STEP[name], dtype)
            for members in args.members:
                if over_budget():
                    out["cut_short"] = True
                    save()
                    return out
                n_steps = args.steps or int(min(1000, max(50, 2.5e8 // members)))
                states = _states(x0, members, dtype)
                if case.endswith("_hand"):
                    fn = jax.jit(lambda x, n=n_steps: _summary(hand_kernel_ensemble(model, x, h, n, save_every=n, chunk=None)))
                else:
                    fn = jax.jit(lambda x, n=n_steps: _summary(_ensemble.ensemble(model, x, h, n, order=order, save_every=n, throw=False)))
                with _fusion_boundaries(args.boundaries):
                    first, median, _ = time_compiled(fn, states, repeats=5)
                    last_xi, converged, iterations, g4, xi4 = fn(states)
                converged = float(converged)
                row = dict(kind="ensemble", case=case, fusion_boundaries=args.boundaries, dtype=dtype_name, members=members, steps=n_steps,
                           compile_and_first_s=first, median_s=median, rate=members * n_steps / median, converged_fraction=converged,
                           max_newton_iterations=int(iterations))
                row["extrapolated_guess"] = args.extrapolation
                if members == args.members[0]:
                    ref = []
                    model64, _ = _scene(name, jnp.float64)
                    for k in range(4):
                        s = vj.simulate(model64, _member(states, k), STEP[name], n_steps, order=order, save_every=n_steps, device="cpu")
                        ref.append((np.asarray(s.g[-1]), np.asarray(s.xi[-1])))
                    row["max_abs_difference_to_cpu_float64_simulate"] = dict(
                        g=float(max(np.max(np.abs(np.asarray(g4[k], np.float64) - r[0])) for k, r in enumerate(ref))),
                        xi=float(max(np.max(np.abs(np.asarray(xi4[k], np.float64) - r[1])) for k, r in enumerate(ref))),
                    )
                out["rows"].append(row)
                print(f"{case:10s} {dtype_name:8s} {members:8d} members x {n_steps:5d} steps: {row['rate'] / 1e9:7.3f} G member-steps/s "
                      f"(compile+first {first:6.1f} s, converged {converged:.3f})", flush=True)
                save()

    if args.single and not over_budget():
        out["rows"] += single_rows(args.single_steps)
        save()

    # plain vmap of vj.simulate for every generated case, float64
    for case in args.cases:
        if case == "vehicle1_hand" or not args.peer_members or over_budget():
            continue
        name, order = CASES[case]
        members = args.peer_members
        n_steps = args.steps or int(min(1000, max(50, 2.5e8 // members)))
        model, x0 = _scene(name, jnp.float64)
        states = _states(x0, members, jnp.float64)
        fn = jax.jit(lambda x: _summary(_ensemble.ensemble(model, x, STEP[name], n_steps, order=order, save_every=n_steps, method="vmap", throw=False)))
        first, median, _ = time_compiled(fn, states, repeats=5)
        out["rows"].append(dict(kind="peer", case=case, implementation='method="vmap"', dtype="float64",
                                members=members, steps=n_steps, compile_and_first_s=first, median_s=median, rate=members * n_steps / median))
        print(f"peer method=vmap {case} {members} members: {members * n_steps / median / 1e9:.3f} G/s", flush=True)
        save()

    # peers for the vehicle at order 1, float64
    if "vehicle1" in args.cases and args.peer_members and not over_budget():
        members = args.peer_members
        n_steps = args.steps or int(min(1000, max(50, 2.5e8 // members)))
        model, x0 = _scene("vehicle", jnp.float64)
        states = _states(x0, members, jnp.float64)
        step = make_step(vehicle_params(model), 0.01)
        mass = model.mass * jnp.eye(3) + model.added_mass

        @jax.jit
        def hand(omegas):
            def one(w):
                carry = (x0.g, x0.q, model.inertia @ w, mass @ (x0.g.T @ x0.qdot), w)
                carry, _ = jax.lax.scan(lambda c, _: (step(c, None)[0], None), carry, None, length=n_steps)
                return carry[4]

            return jax.vmap(one)(omegas)

        first, median, _ = time_compiled(hand, states.xi, repeats=5)
        out["rows"].append(dict(kind="peer", case="vehicle1", implementation="plain vmap, hand step", dtype="float64",
                                members=members, steps=n_steps, compile_and_first_s=first, median_s=median, rate=members * n_steps / median))
        print(f"peer plain vmap hand step {members} members: {members * n_steps / median / 1e9:.3f} G/s", flush=True)
        save()
        if not over_budget():
            members = min(members, CPU_PLAN_MEMBERS)
            states = _states(x0, members, jnp.float64)
            real = _ensemble.target_platform
            _ensemble.target_platform = lambda mesh=None: "cpu"  # the CPU plan: chunks of 64 members
            try:
                first, median, _ = time_compiled(final(model, 0.01, n_steps), states, repeats=5)
            finally:
                _ensemble.target_platform = real
            out["rows"].append(dict(kind="peer", case="vehicle1", implementation="vj.ensemble, CPU plan (chunks of 64)", dtype="float64",
                                    members=members, steps=n_steps, compile_and_first_s=first, median_s=median, rate=members * n_steps / median))
            print(f"peer vj.ensemble, CPU plan {members} members: {members * n_steps / median / 1e9:.3f} G/s", flush=True)
            save()
    return out


def single_one(n_steps, where):
    """µs per step of one vehicle trajectory (order 1, every node saved) in this process."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import vi_jax as vj

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    device = "cpu" if where == "cpu" else None
    first, median, _ = time_compiled(lambda x: vj.simulate(model, x, 0.01, n_steps, device=device).q, x0, repeats=5)
    return dict(kind="single", where=where, device=str(jax.devices("cpu" if where == "cpu" else None)[0]),
                steps=n_steps, compile_and_first_s=first, median_s=median, us_per_step=median / n_steps * 1e6)


def single_rows(n_steps):
    import warnings

    from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows.append(single_one(n_steps, "default device"))
    for config, flags in (("cpu, default XLA flags", ""), ("cpu, loop option", FAST_LOOPS_FLAG)):
        env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
        run = subprocess.run([sys.executable, __file__, "--single-child", str(n_steps * 10)], env=env, stdout=subprocess.PIPE, text=True, check=True)
        row = json.loads(run.stdout.strip().splitlines()[-1])
        row["where"] = config
        rows.append(row)
    for row in rows:
        print(f"single trajectory, {row['where']:24s} ({row['device']}): {row['us_per_step']:8.2f} µs/step", flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--members", type=int, nargs="+", default=[1024, 32768, 1048576])
    parser.add_argument("--dtypes", nargs="+", default=["float64", "float32"])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--steps", type=int, default=None, help="steps per run (default: min(1000, 2.5e8 / members))")
    parser.add_argument("--peer-members", type=int, default=32768, help="members for the peer rows (0: none)")
    parser.add_argument("--budget-s", type=float, default=520.0, help="start no new measurement after this")
    parser.add_argument("--boundaries", action="store_true", help="keep the generated step's fusion boundaries on a GPU too")
    parser.add_argument("--no-single", dest="single", action="store_false")
    parser.add_argument("--extrapolation", action="store_true",
                        help="the generated step starts Newton from 2 xi_k - xi_{k-1} (the accelerator plan's default: xi_k)")
    parser.add_argument("--single-steps", type=int, default=5000)
    parser.add_argument("--single-child", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--out", default=str(HERE / "results" / "ensemble_gpu.json"))
    args = parser.parse_args()
    if args.single_child:
        print(json.dumps(single_one(args.single_child, "cpu")))
        return
    measure(args)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
