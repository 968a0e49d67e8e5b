"""``vi-jax simulate underwater``: the underwater vehicle of seed 000 (the paper's run by default).

Writes ``DIR/trajectory.npz`` (t, R, q, omega, nu, energy, kelvin_noether; leading axis = time)
and the PNG analogues of the paper's Figures 1–3.
"""

from pathlib import Path


def add_underwater_arguments(sim):
    sim.add_argument("--tau", default="cayley", choices=["cayley", "exp"], help="group difference map")
    sim.add_argument("--order", type=int, default=1, choices=[1, 2, 4, 6], help="1 = the paper's rule (eq. 71)")
    sim.add_argument("--h", type=float, default=0.01, help="time step [s]")
    sim.add_argument("--steps", type=int, default=50_000, help="number of steps")
    sim.add_argument("--save-every", type=int, default=1, help="save every k-th node")
    sim.add_argument("--float32", action="store_true", help="run in float32 (default float64)")
    sim.add_argument("--out", type=Path, default=Path("out/underwater"), help="output directory")
    sim.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run_underwater(args):
    import jax

    jax.config.update("jax_enable_x64", not args.float32)
    import numpy as np

    import vi_jax as vj
    from vi_jax.plots import plot_vehicle_run

    model = vj.models.UnderwaterVehicle()
    sol = vj.simulate(
        model, model.initial_state(), args.h, args.steps, tau=args.tau, order=args.order,
        save_every=args.save_every, progress=not args.no_progress,
        device="cpu",  # a single trajectory is latency-bound on an accelerator (README: where to run)
    )
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez(
        args.out / "trajectory.npz",
        t=sol.t, R=sol.R, q=sol.q, omega=sol.omega, nu=sol.nu,
        energy=sol.energy, kelvin_noether=sol.kelvin_noether,
    )
    label = f"{args.tau}, order {args.order}, h = {args.h:g}"
    paths = plot_vehicle_run({label: sol}, args.out)
    energy = np.asarray(sol.energy)
    kn = np.asarray(sol.kelvin_noether)
    print(f"q(T) = {np.asarray(sol.q[-1])}")
    print(f"max |ΔE/E₀| = {np.max(np.abs(energy / energy[0] - 1)):.3e}")
    print(f"max |ΔI/I₀| = {np.max(np.abs(kn / kn[0] - 1)):.3e}")
    print(f"wrote {args.out / 'trajectory.npz'} and " + ", ".join(p.name for p in paths))
