"""Figures of the work-precision study (``vi_jax.studies.work_precision``): error against run
time, the long-horizon invariants against run time, and the energy error along a run."""

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from ..studies.work_precision import ACCURACIES



def _style(peer):
    """vi_jax: solid, colour by order, marker by scheme (Cayley ●, exp □, splitting ◆, thick);
    diffrax: dashed, colour by solver, dotted on a hand-written vector field."""
    if peer.startswith("vi_jax"):
        _, scheme, _, order = peer.split()
        colour = {"1": "tab:red", "2": "tab:orange", "4": "tab:green", "6": "tab:purple", "8": "tab:pink"}[order]
        marker = {"cayley": "o", "exp": "s", "splitting": "D"}[scheme]
        return dict(color=colour, ls="-", lw=2.2 if scheme == "splitting" else 1, marker=marker,
                    mfc="none" if scheme == "exp" else colour)
    colour = {"Tsit5": "tab:blue", "Dopri5": "tab:cyan", "Dopri8": "navy", "Kvaerno5": "tab:brown", "RK4": "black"}[peer.split()[1]]
    return dict(color=colour, ls=":" if "field" in peer else "--", lw=1, marker="^" if "PID" in peer else "x")


def _plot_curves(ax, peers, key):
    for peer, rows in peers.items():
        pts = sorted((r["median_s"], r[key]) for r in rows if r[key] is not None)
        if pts:
            ax.loglog(*zip(*pts), ms=4, label=peer, **_style(peer))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="both", alpha=0.3)
    ax.set_xlabel("compiled run time [s] (median)")


def plot_work_precision(result, path):
    systems = result["work_precision"]
    fig = Figure(figsize=(7.5 * len(systems), 5.5))
    axes = fig.subplots(1, len(systems), squeeze=False)
    for ax, (name, data) in zip(axes[0], systems.items()):
        _plot_curves(ax, data["peers"], "error")
        ax.axhspan(min(ACCURACIES), max(ACCURACIES), color="0.9", zorder=0)
        ax.set_ylabel("relative final-state error at T")
        ax.set_title(f"{data['system']}, T = {data['T']:g} s", fontsize=9)
        ax.legend(fontsize=6.5, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_long_horizon(result, path):
    data = result["long_horizon"]
    fig = Figure(figsize=(17, 5))
    axes = fig.subplots(1, 3)
    labels = (("energy_error", "max |E/E₀ − 1|"), ("kelvin_noether_error", "max |I − I₀| / scale"), ("group_drift", "max ‖RᵀR − I‖"))
    for ax, (key, ylabel) in zip(axes, labels):
        _plot_curves(ax, data["peers"], key)
        ax.set_ylabel(ylabel)
    axes[0].legend(fontsize=7)
    rk4 = f"; RK4: {data['rk4_steps']:,} steps" if data["rk4_steps"] else ""
    fig.suptitle(f"{data['system']}, T = {data['T']:g} s (vi_jax step counts in the table{rk4})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_energy_vs_time(result, path):
    data = result["long_horizon"]
    fig = Figure(figsize=(8, 5.5))
    ax = fig.subplots()
    for peer, s in data["energy_vs_time"].items():
        style = _style(peer)
        style.pop("marker"), style.pop("mfc", None)
        style["lw"] = 1.2 * style["lw"]
        running_max = np.maximum.accumulate(np.maximum(s["energy_error"], 1e-17))
        ax.loglog(s["t"], running_max, label=f"{peer} ({s['setting']})", **style)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("max over [0, t] of |E/E₀ − 1| (saved nodes)")
    ax.set_title(f"{data['system']}: energy error along the run", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
