"""XLA:CPU's elemental emitters against its default fusion emitters, per program, in one process:
the choice behind ``vi_jax/engine/_compile_options.py`` (single trajectories get the elemental
ones, ensembles keep the fusion ones).

    python benchmarks/emitters.py [--fast-loops]

Each case is one jitted call (scene, states and h as arguments), lowered once and compiled twice
per emitter, alternately (``compiler_options={"xla_cpu_use_fusion_emitters": False}`` or not):
backend compile seconds, and the median of 5 compiled runs per step (single trajectories:
20,000 steps, every node saved; the beam's time march: 16 nodes, 2000 steps) or per member-step (ensembles: 1024 members × 1000 steps, final
node saved, ``vj.ensemble``'s default path under ``jit``) or per evaluation (the fit's residuals
and Jacobian: :func:`fit_cases`). A program compiled anew is cached by
XLA's in-process cache after its first compile: the second compile of each pair is timed on a
program whose HLO differs by a unique constant.
"""

import statistics
import time

from _timing import parse_args_with_fast_loops, write_config_json

ARGS = parse_args_with_fast_loops()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax.engine._compile_options import ELEMENTAL_EMITTERS  # noqa: E402

STEPS = 20_000
BEAM_NODES, BEAM_STEPS = 16, 2000
MEMBERS, MEMBER_STEPS = 1024, 1000
EMITTERS = {"fusion (XLA's default)": None, "elemental": ELEMENTAL_EMITTERS}


def measure(f, args, units, repeats=5):
    """Per emitter: (compile seconds of two fresh programs, median seconds per unit)."""
    out = {}
    for name, options in EMITTERS.items():
        compiles, runs = [], []
        for salt in (0.0, 1e-300):  # a distinct program each time: no in-process cache hit
            lowered = jax.jit(lambda *a, salt=salt: jax.tree.map(lambda x: x + salt, f(*a))).lower(*args)
            start = time.perf_counter()
            compiled = lowered.compile(compiler_options=options) if options else lowered.compile()
            compiles.append(time.perf_counter() - start)
            jax.block_until_ready(compiled(*args))
            for _ in range(repeats):
                start = time.perf_counter()
                jax.block_until_ready(compiled(*args))
                runs.append(time.perf_counter() - start)
        out[name] = dict(compile_s=compiles, us_per_unit=statistics.median(runs) / units * 1e6)
    return out


def fit_cases():
    """The fit of ``benchmarks/fit_time.py`` (200 samples over 60 s, h = 0.05, order 1): its
    residuals with their Jacobian at the first guess, for its multiple-shooting stages (64
    segments) and its single-shooting stage, per evaluation."""
    import numpy as np
    from fit_time import fit_problem

    from vi_jax.fitting import _fit
    from vi_jax.fitting._parametrisation import FreeParameters, Parametrisation
    from vi_jax.fitting._shooting import Layout, residuals_and_jacobian, samples_of

    _, t, data, guess = fit_problem()
    model_of = FreeParameters(Parametrisation(guess), guess, _fit.DEFAULT_FREE)
    n_steps = int(np.ceil(60.0 / _fit.DEFAULT_H - 1e-9))
    cases = []
    for segments in (_fit.MAX_SEGMENTS, 1):
        layout = Layout(t, 0.0, _fit.DEFAULT_H, segments, n_steps)
        states, R_ref = _fit.estimate_states(data, layout.start_times(), _fit._identity_fallback(segments))
        run = lambda th, s, R, samples, layout=layout: residuals_and_jacobian(  # noqa: E731
            th, s, R, model_of, layout, samples, jnp.asarray(1.0), "squared", "cayley", 1
        )[:2]
        args = (model_of.initial(), jnp.asarray(states), jnp.asarray(R_ref), samples_of(data))
        cases.append((f"fit Jacobian, {segments} segment{'s' * (segments > 1)}", run, args, 1))
    return cases


def main():
    scenes = {"vehicle": vj.models.UnderwaterVehicle(), "heavy_top": vj.models.HeavyTop(), "rigid_body": vj.models.RigidBody()}
    cases = []
    for name in ("vehicle", "heavy_top"):
        for order in (1, 2):
            run = lambda m, x, order=order: vj.simulate(m, x, 0.01, STEPS, order=order, throw=False)  # noqa: E731
            cases.append((f"simulate {name} order {order}", run, (scenes[name], scenes[name].initial_state()), STEPS))
    split = lambda m, x: vj.simulate(m, x, 0.05, STEPS, scheme="splitting", order=4, throw=False)  # noqa: E731
    cases.append(("simulate vehicle splitting order 4", split, (scenes["vehicle"], scenes["vehicle"].initial_state()), STEPS))
    beam = vj.models.GeometricallyExactBeam()
    g0, xi0 = beam.initial_state(BEAM_NODES)
    march = lambda g, xi: vj.multisymplectic.time_march(beam, g, xi0=xi, dt=1e-4, ds=float(beam.length) / BEAM_NODES, n_steps=BEAM_STEPS).g  # noqa: E731
    cases.append((f"beam time march, {BEAM_NODES} nodes", march, (g0, xi0), BEAM_STEPS))
    for name, model in scenes.items():
        x0 = model.initial_state()
        members = vj.vary(x0, xi=x0.xi * (1 + 0.1 * jnp.linspace(0, 1, MEMBERS))[:, None])
        for order in (1, 2):
            run = lambda m, x, order=order: vj.ensemble(m, x, 0.01, MEMBER_STEPS, order=order, save_every=MEMBER_STEPS, throw=False).M  # noqa: E731
            cases.append((f"ensemble {name} order {order}", run, (model, members), MEMBERS * MEMBER_STEPS))
    cases += fit_cases()
    rows = []
    print(f"{'case':36s} {'compile fusion / elemental [s]':>32s} {'run fusion / elemental [us per unit]':>38s}")
    for label, f, args, units in cases:
        result = measure(f, args, units)
        fusion, elemental = result.values()
        rows.append(dict(case=label, units=units, **result))
        print(f"{label:36s} {min(fusion['compile_s']):14.2f} / {min(elemental['compile_s']):5.2f} (x{min(elemental['compile_s']) / min(fusion['compile_s']):.2f})"
              f" {fusion['us_per_unit']:14.4f} / {elemental['us_per_unit']:.4f} (x{elemental['us_per_unit'] / fusion['us_per_unit']:.2f})", flush=True)
    write_config_json("emitters", ARGS.fast_loops, rows=rows)


if __name__ == "__main__":
    main()
