"""Figures of a parameter fit: the loss per iteration with the horizon stages marked."""

import numpy as np


def plot_loss(result, path):
    from matplotlib.figure import Figure  # pyplot-free: no backend is selected or changed

    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    history = np.maximum(result.loss_history, 1e-30)
    ax.semilogy(np.arange(1, history.size + 1), history, lw=1.0, marker=".", ms=3)
    for k, start in enumerate(result.stage_starts[1:], 1):
        ax.axvline(start + 0.5, color="0.6", lw=0.8, ls="--")
        ax.text(start + 1, history.max(), f"stage {k + 1}", fontsize=7, va="top", color="0.4")
    ax.set_xlabel("iteration")
    ax.set_ylabel(r"$\frac{1}{2}\,\sum r^2 / \sum w$ (whitened)")
    ax.set_title("Fit of the underwater vehicle's parameters")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
