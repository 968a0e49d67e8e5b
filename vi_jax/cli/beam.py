"""``vi-jax simulate beam``: the geometrically exact beam of seed 003.

  vi-jax simulate beam --out DIR                      # free–free time march (default)
  vi-jax simulate beam --scenario clamped --out DIR   # clamped–free time march
  vi-jax simulate beam --scenario paper --out DIR     # §5: the space march from the paper's data

writes ``DIR/beam.npz`` (``t``, ``s``, ``g`` (time, node, 4, 4), ``momentum`` (time, 6),
``energy`` (time,); the paper scenario adds ``space_momentum`` and ``space_energy`` per column
and ``valid_columns``) and the PNGs ``beam_shapes.png`` and ``conservation.png``.
"""

import argparse
import warnings
from pathlib import Path

SCENARIOS = ("free", "clamped", "paper")
PAPER_SHAPE_TIMES = (0.1, 0.6, 1.25, 1.4, 1.45, 1.95)  # Fig. 7 (nearest rows: Δt = 0.04 s)


def add_beam_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``vi-jax simulate beam``."""
    parser.add_argument("--scenario", default="free", choices=SCENARIOS,
                        help="free: free–free time march from a twisted, moving beam (default); "
                        "clamped: clamped–free time march; paper: seed 003 §5 space march")
    parser.add_argument("--nodes", type=int, default=10, help="massive nodes of the time march (Δs = L/nodes)")
    parser.add_argument("--dt", type=float, default=None,
                        help="time step [s] (default: half the time march's stability limit; 0.04 for the paper)")
    parser.add_argument("--duration", type=float, default=None,
                        help="duration [s] (default: 1 for a time march, 2 for --scenario paper)")
    parser.add_argument("--save-every", type=int, default=10, help="save every k-th time row")
    parser.add_argument("--length", type=float, default=0.8, help="beam length L [m]")
    parser.add_argument("--side", type=float, default=0.01, help="side of the square cross-section [m]")
    parser.add_argument("--youngs-modulus", type=float, default=5e6, help="E [Pa] (assumed; the paper gives none)")
    parser.add_argument("--poisson-ratio", type=float, default=0.35, help="ν (assumed)")
    parser.add_argument("--mass-density", type=float, default=1000.0, help="ρ [kg/m³] (assumed)")
    parser.add_argument("--twist", type=float, default=2.0, help="initial pre-twist [rad/m] (time march)")
    parser.add_argument("--out", type=Path, default=Path("out/beam"), help="output directory")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _check(args):
    if args.scenario not in SCENARIOS:
        raise ValueError(f"--scenario: expected one of {SCENARIOS}, got {args.scenario!r}")
    for name in ("duration", "length", "side", "youngs_modulus", "mass_density"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise ValueError(f"--{name.replace('_', '-')}: expected a number > 0, got {value!r}")
    if args.dt is not None and not args.dt > 0:
        raise ValueError(f"--dt: expected a number > 0, got {args.dt!r}")
    if args.nodes < (2 if args.scenario == "clamped" else 1):
        raise ValueError(f"--nodes: expected ≥ {2 if args.scenario == 'clamped' else 1}, got {args.nodes}")
    if args.save_every < 1:
        raise ValueError(f"--save-every: expected an integer ≥ 1, got {args.save_every}")


def run_beam(args) -> None:
    """Run the chosen scenario and write the data and figures to ``args.out``."""
    _check(args)
    import jax

    jax.config.update("jax_enable_x64", True)
    from ..models._beam import GeometricallyExactBeam

    model = GeometricallyExactBeam(
        args.length, args.side, args.youngs_modulus, args.poisson_ratio, args.mass_density
    )
    args.out.mkdir(parents=True, exist_ok=True)
    if args.scenario == "paper":
        data = _paper(model, args)
    else:
        data = _time_march(model, args)
    import numpy as np

    np.savez(args.out / "beam.npz", **{k: np.asarray(v) for k, v in data.items()})
    print(f"wrote {args.out / 'beam.npz'}, beam_shapes.png and conservation.png")


def _time_march(model, args):
    import numpy as np

    from ..plots.beam import plot_beam_shapes, plot_conservation
    from ..multisymplectic._time import time_march

    ds = float(model.length) / args.nodes
    limit = float(model.stable_time_step(ds))
    dt = 0.5 * limit if args.dt is None else args.dt
    if dt > limit:
        warnings.warn(
            f"--dt {dt:.3g} s exceeds the time march's stability estimate {limit:.3g} s (spec §6)", stacklevel=2
        )
    n_steps = max(1, int(round((1.0 if args.duration is None else args.duration) / dt)))
    save_every = min(args.save_every, n_steps)
    n_steps -= n_steps % save_every
    g0, xi0 = model.initial_state(args.nodes, twist=args.twist)
    boundary = "free-free"
    if args.scenario == "clamped":
        boundary, xi0 = "clamped-free", xi0.at[0].set(0.0)
    sol = time_march(
        model, g0, xi0=xi0, dt=dt, ds=ds, n_steps=n_steps, boundary=boundary, save_every=save_every,
        progress=not args.no_progress,
    )
    J, E = np.asarray(sol.momentum), np.asarray(sol.energy)
    title = f"{boundary}, {args.nodes} nodes, Δt = {dt:.3g} s"
    t_end = float(sol.t[-1])
    plot_beam_shapes(sol.t, sol.g, np.linspace(0, t_end, 6), args.out / "beam_shapes.png", title=title)
    plot_conservation(sol.t, J, E, args.out / "conservation.png", title=boundary)
    print(f"{boundary}: {n_steps} steps of Δt = {dt:.4g} s (stability estimate {limit:.4g} s), Δs = {ds:.4g} m")
    if boundary == "free-free":  # the clamp's reaction changes J
        print(f"max |J − J(0)| / |J(0)| = {np.max(np.abs(J - J[0])) / np.linalg.norm(J[0]):.3e}")
    print(f"energy band (max − min) / E(0) = {np.ptp(E) / abs(E[0]):.3e}")
    return dict(t=sol.t, s=sol.s, g=sol.g, momentum=J, energy=E)


def _paper(model, args):
    import numpy as np

    from ..models._beam import PAPER_DS, PAPER_DT, PAPER_DURATION
    from ..multisymplectic._noether import time_energy, time_momentum_map
    from ..plots.beam import plot_beam_shapes, plot_conservation
    from ..multisymplectic._space import space_march

    dt = PAPER_DT if args.dt is None else args.dt
    duration = PAPER_DURATION if args.duration is None else args.duration
    n_columns = int(round(float(model.length) / PAPER_DS)) + 1
    col0, col1 = model.paper_space_data(dt, PAPER_DS, duration)
    sol = space_march(model, col0, col1, dt=dt, ds=PAPER_DS, n_columns=n_columns, throw=False)
    valid = sol.valid_columns
    if valid < n_columns:
        warnings.warn(
            f"paper scenario: only columns 0..{valid - 1} (s ≤ {(valid - 1) * PAPER_DS:.3g} m) come from converged "
            "solves; the data are inconsistent (see the warnings above), so the output stops there.",
            stacklevel=2,
        )
    g = sol.g[:, :valid]  # rows 0..N with the ghost row N
    momentum = time_momentum_map(model, g, dt=dt, ds=PAPER_DS)  # 𝖩_𝖫(j): not conserved here (§5)
    energy = time_energy(model, g, dt=dt, ds=PAPER_DS)
    t = sol.t[:-1]
    solved = max(valid - 1, 1)  # λ_a, hence 𝖩_𝖭(a) and E_N(a), come from the solve at column a
    plot_beam_shapes(t, g[:-1], PAPER_SHAPE_TIMES, args.out / "beam_shapes.png", title=f"seed 003 §5 ({valid} columns)")
    plot_conservation(sol.s[:solved], sol.momentum[:solved], sol.energy[:solved], args.out / "conservation.png",
                      xlabel="s [m]", title="space march")
    J = np.asarray(sol.momentum[:solved])
    print(f"paper: {valid} of {n_columns} columns; max |J_N − J_N(0)| / |J_N(0)| over the solved columns = "
          f"{np.max(np.abs(J - J[0])) / np.linalg.norm(J[0]):.3e}")
    return dict(
        t=t, s=sol.s[:valid], g=g[:-1], momentum=momentum, energy=energy,
        space_momentum=sol.momentum[:solved], space_energy=sol.energy[:solved], valid_columns=valid,
    )
