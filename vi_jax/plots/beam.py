"""Figures of a beam run: centreline shapes at several times (the analogue of seed 003 Fig. 7)
and the relative errors of the conserved quantities (Fig. 6)."""

import numpy as np


def _figure(**kwargs):
    """A pyplot-free figure: no backend is selected or changed."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def plot_beam_shapes(t, g, times, path, title="beam centreline"):
    """3-D centrelines r_a(t) (g: (time, node, 4, 4)) at the rows nearest to ``times``, with the
    body axis Λe₁ of each section drawn as a short tick (shows the twist)."""
    t, g = np.asarray(t), np.asarray(g)
    rows = sorted({int(np.argmin(np.abs(t - x))) for x in times})
    r = g[..., :3, 3]
    span = np.ptp(r.reshape(-1, 3), axis=0).max()
    from matplotlib import colormaps

    fig = _figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    colours = colormaps["viridis"](np.linspace(0, 1, len(rows)))
    for colour, j in zip(colours, rows):
        ax.plot(*r[j].T, "-o", ms=2, lw=1.2, color=colour, label=f"t = {t[j]:.3g} s")
        ticks = r[j] + 0.06 * span * g[j, :, :3, 0]
        for a, b in zip(r[j], ticks):
            ax.plot(*np.stack([a, b]).T, lw=0.6, color=colour)
    centre = 0.5 * (r[rows].reshape(-1, 3).max(0) + r[rows].reshape(-1, 3).min(0))
    half = 0.55 * np.ptp(r[rows].reshape(-1, 3), axis=0).max()
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - half, c + half)  # equal scales: true shapes
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _relative(values, scale):
    values = np.asarray(values)
    return np.abs(values - values[0]) / scale


def plot_conservation(x, momentum, energy, path, xlabel="t [s]", title="time march"):
    """Semilog relative errors: |𝖩_k − 𝖩_k(0)| / |𝖩(0)| for the six components and
    |E − E(0)| / |E(0)|, against ``x`` (time or arc length)."""
    x, momentum, energy = np.asarray(x), np.asarray(momentum), np.asarray(energy)
    fig = _figure(figsize=(11, 4))
    ax1, ax2 = fig.subplots(1, 2)
    labels = ["$J_{\\omega,1}$", "$J_{\\omega,2}$", "$J_{\\omega,3}$", "$J_{v,1}$", "$J_{v,2}$", "$J_{v,3}$"]
    scale = np.linalg.norm(momentum[0])
    for k in range(momentum.shape[1]):
        ax1.semilogy(x[1:], np.maximum(_relative(momentum[:, k], scale)[1:], 1e-18), lw=0.8, label=labels[k])
    ax1.set_title(f"{title}: momentum map, relative to |J(0)|")
    ax2.plot(x, (energy - energy[0]) / abs(energy[0]), lw=0.8)
    ax2.set_title(f"{title}: relative energy error")
    for ax in (ax1, ax2):
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
