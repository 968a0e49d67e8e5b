"""Figures of a parameter fit: the loss per iteration with the stages marked, the fitted model
against the telemetry per channel, and the whitened residuals."""

import numpy as np

from ..fitting._csv import EULER, VECTOR_COLUMNS, _matrix_to_euler
from ..fitting._telemetry import UNITS
from ..lie._so3 import unskew3


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


_COMPONENTS = {**VECTOR_COLUMNS, "attitude": EULER}  # the CSV columns of each channel


def _observed_and_fitted(result, telemetry, channel):
    obs, fitted = np.asarray(telemetry.values[channel]), result.prediction[channel]
    if channel == "attitude":  # angles continued past ±π along the fitted motion
        obs, wrapped = _matrix_to_euler(obs), _matrix_to_euler(fitted)
        fitted = np.unwrap(wrapped, axis=0)
        obs = obs + 2 * np.pi * np.round((fitted - obs) / (2 * np.pi))
    return obs, fitted, np.asarray(telemetry.mask[channel]) > 0


def _per_channel_figure(telemetry, path, title, height, draw):
    """One panel per given channel, ``draw(ax, channel, t)`` filling each, saved to ``path``."""
    from matplotlib.figure import Figure

    channels = telemetry.channels
    fig = Figure(figsize=(8, height * len(channels)))
    axes = np.atleast_1d(fig.subplots(len(channels), 1, sharex=True))
    for ax, c in zip(axes, channels):
        draw(ax, c, np.asarray(telemetry.t))
        ax.legend(fontsize=6, ncol=3, loc="upper right")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_channels(result, telemetry, path):
    """Fitted model (lines, at the sample times) against the observed samples (dots), one panel
    per observed channel; attitudes as ZYX angles, continued past ±π."""

    def draw(ax, c, t):
        obs, fitted, mask = _observed_and_fitted(result, telemetry, c)
        for k, name in enumerate(_COMPONENTS[c]):
            if mask[:, k].any():
                (line,) = ax.plot(t, fitted[:, k], lw=1.0, label=f"{name} fitted")
                ax.plot(t[mask[:, k]], obs[mask[:, k], k], ".", ms=3, color=line.get_color(), label=f"{name} observed")
        ax.set_ylabel(f"{c} [{UNITS[c]}]")

    _per_channel_figure(telemetry, path, "Fitted model against the telemetry", 2.4, draw)


def plot_residuals(result, telemetry, path):
    """Residuals in units of each channel's σ against time (attitude: the rotation vector of
    R_obsᵀR_fit), with ±1σ and ±3σ bands: an honest noise model leaves them ~N(0, 1)."""

    def draw(ax, c, t):
        obs, fitted, mask = np.asarray(telemetry.values[c]), result.prediction[c], np.asarray(telemetry.mask[c]) > 0
        if c == "attitude":
            diff = np.asarray(unskew3(np.einsum("nji,njk->nik", obs, fitted)))
        else:
            diff = fitted - obs
        for k, name in enumerate(("x", "y", "z") if c == "attitude" else _COMPONENTS[c]):
            if mask[:, k].any():
                ax.plot(t[mask[:, k]], diff[mask[:, k], k] / telemetry.sigma[c], ".", ms=3, label=name)
        for band, alpha in ((1, 0.15), (3, 0.07)):
            ax.axhspan(-band, band, color="0.5", alpha=alpha, lw=0)
        ax.set_ylabel(f"{c} / σ")

    _per_channel_figure(telemetry, path, "Whitened residuals", 2.0, draw)
