"""Figures of a run: relative energy and Kelvin–Noether errors (semilog) and the trajectory —
the analogues of seed 000 Figures 1–3. Each function overlays several labelled solutions."""

import numpy as np
from matplotlib.figure import Figure  # pyplot-free: no backend is selected or changed


def _relative_error(values):
    values = np.asarray(values)
    if values.ndim > 1:
        values = np.linalg.norm(values, axis=-1)
    return np.abs(values - values[0]) / np.abs(values[0])


def _semilog(solutions, quantity, ylabel, title, path):
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for label, sol in solutions.items():
        err = _relative_error(getattr(sol, quantity))
        ax.semilogy(np.asarray(sol.t)[1:], np.maximum(err[1:], 1e-17), lw=0.8, label=label)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_energy_error(solutions, path):
    """Figure 1: |E_k − E₀| / |E₀|."""
    _semilog(solutions, "energy", r"$|E_k - E_0| / |E_0|$", "Relative energy error", path)


def plot_kelvin_noether_error(solutions, path):
    """Figure 2: |I_k − I₀| / |I₀|."""
    _semilog(solutions, "kelvin_noether", r"$|I_k - I_0| / |I_0|$", "Relative Kelvin–Noether error", path)


def plot_trajectory(solutions, path):
    """Figure 3: the 3-D path of q and its components against t."""
    fig = Figure(figsize=(11, 4.5))
    ax3d = fig.add_subplot(1, 2, 1, projection="3d")
    axes = [fig.add_subplot(3, 2, 2 * i + 2) for i in range(3)]
    for label, sol in solutions.items():
        q, t = np.asarray(sol.q), np.asarray(sol.t)
        ax3d.plot(q[:, 0], q[:, 1], q[:, 2], lw=0.8, label=label)
        for i, ax in enumerate(axes):
            ax.plot(t, q[:, i], lw=0.8, label=label)
    ax3d.set_xlabel("x [m]")
    ax3d.set_ylabel("y [m]")
    ax3d.set_zlabel("z [m]")
    ax3d.set_title("trajectory of q")
    ax3d.legend()
    for i, ax in enumerate(axes):
        ax.set_ylabel(f"$q_{'xyz'[i]}$ [m]")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_vehicle_run(solutions, out_dir):
    """Write energy_error.png, kelvin_noether_error.png and trajectory.png into ``out_dir``."""
    from pathlib import Path

    out = Path(out_dir)
    paths = [out / "energy_error.png", out / "kelvin_noether_error.png", out / "trajectory.png"]
    for plot, path in zip((plot_energy_error, plot_kelvin_noether_error, plot_trajectory), paths):
        plot(solutions, path)
    return paths
