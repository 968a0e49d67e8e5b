"""Figure 1 of seed 002 (Clebsch–Cayley rigid body, I = (0.5, 0.6, 1), Δt = 0.1): initial
momenta on the Casimir sphere |Π| = 1, revolution counts, and the figure itself."""

import numpy as np


def figure1_initial_momenta(angles=(0.3, 0.6, 0.9, 1.2), offsets=(0.02, 0.06)):
    """Unit body momenta Π(0): tilted by ``angles`` from ±e₁ towards e₂ and from ±e₃ towards e₂
    (the stable axes of the smallest and largest moment), and ``offsets`` away from ±e₂
    (the unstable axis) towards e₁ and e₃, just either side of the separatrix.
    Returns (k, 3) momenta and k family labels."""
    momenta, labels = [], []
    for sign in (1.0, -1.0):
        for a in angles:
            momenta.append((sign * np.cos(a), np.sin(a), 0.0))
            labels.append("axis 1")
            momenta.append((0.0, np.sin(a), sign * np.cos(a)))
            labels.append("axis 3")
        for d in offsets:
            for direction in ((d, 0.0), (0.0, d)):
                x, z = direction
                momenta.append((x, sign * np.sqrt(1.0 - d * d), z))
                labels.append("separatrix")
    return np.asarray(momenta), labels


def revolutions(mu, inertia_diag):
    """Number of revolutions of each body-momentum orbit (k, n, 3) about the stable axis it
    circles (axis 1 if 2E/|Π|² > 1/I₂, else axis 3): the unwrapped angle of the projection on
    the plane normal to that axis, / 2π."""
    mu = np.asarray(mu)
    I = np.asarray(inertia_diag)
    ratio = np.sum(mu[:, 0] ** 2 / I, axis=-1) / np.sum(mu[:, 0] ** 2, axis=-1)
    out = []
    for traj, r in zip(mu, ratio):
        j, k = (1, 2) if r > 1.0 / I[1] else (0, 1)
        angle = np.unwrap(np.arctan2(traj[:, k], traj[:, j]))
        out.append(abs(angle[-1] - angle[0]) / (2 * np.pi))
    return np.asarray(out)


def _sphere(ax, view):
    """Light sphere, its equator/meridians and the body axes, seen from the unit vector ``view``."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 61), np.linspace(0, np.pi, 31))
    ax.plot_surface(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.93", alpha=0.35, lw=0)
    s = np.linspace(0, 2 * np.pi, 200)
    for circle in (np.stack([np.cos(s), np.sin(s), 0 * s]), np.stack([np.cos(s), 0 * s, np.sin(s)]),
                   np.stack([0 * s, np.cos(s), np.sin(s)])):
        _plot_visible(ax, circle.T, view, color="0.75", lw=0.5)
    for i, name in enumerate(("Π₁", "Π₂", "Π₃")):
        end = np.eye(3)[i] * 1.3
        ax.plot(*zip(end / 1.3, end), color="0.3", lw=0.8)
        ax.text(*(end * 1.06), name, fontsize=10)
    ax.set_box_aspect((1, 1, 1), zoom=1.45)
    ax.set_axis_off()


def _plot_visible(ax, points, view, **kwargs):
    """Plot the part of a curve on the unit sphere that faces the viewer."""
    points = np.array(points, dtype=float)
    points[points @ view < 0] = np.nan
    ax.plot(*points.T, **kwargs)


def figure1(t, mu, energy, spatial, labels, inertia_diag, h, path=None, max_points=6000):
    """Left: the orbits of μ̃ (≈ Π) on the sphere, front and back views, coloured by family;
    right: relative energy error and relative drift of |μ̃| and of the spatial momentum, worst
    over the orbits. Arrays have leading axes (orbit, node). Saves a PNG when ``path`` is given."""
    import matplotlib.pyplot as plt

    t, mu, energy, spatial = map(np.asarray, (t, mu, energy, spatial))
    colours = {"axis 1": "tab:blue", "axis 3": "tab:green", "separatrix": "tab:red"}
    stride = max(1, mu.shape[1] // max_points)
    fig = plt.figure(figsize=(14, 6))
    grid = fig.add_gridspec(2, 3, width_ratios=(1.15, 1.15, 1.0))
    for col, (elev, azim) in enumerate(((25, 30), (-25, 210))):
        ax = fig.add_subplot(grid[:, col], projection="3d")
        e, a = np.radians(elev), np.radians(azim)
        view = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        _sphere(ax, view)
        for traj, label in zip(mu, labels):
            _plot_visible(ax, traj[::stride] / np.linalg.norm(traj[:1]), view, color=colours[label], lw=0.6)
        ax.view_init(elev, azim)
        ax.set_title(f"orbits of the body momentum, {'front' if col == 0 else 'back'}", fontsize=10)
    for label, colour in colours.items():
        ax.plot([], [], color=colour, label=label)
    ax.legend(loc="lower right", fontsize=8)
    ax = fig.add_subplot(grid[0, 2])
    rel_energy = np.max(np.abs(energy / energy[:, :1] - 1), axis=0)
    ax.plot(t[::stride], rel_energy[::stride], lw=0.5)
    ax.set_ylabel("max |E/E₀ − 1|")
    ax.set_title("energy error: bounded, O(h²), no drift", fontsize=10)
    ax = fig.add_subplot(grid[1, 2])
    norms = np.linalg.norm(mu, axis=-1)
    drift_norm = np.max(np.abs(norms / norms[:, :1] - 1), axis=0)
    drift_spatial = np.max(np.linalg.norm(spatial - spatial[:, :1], axis=-1) / norms[:, :1], axis=0)
    ax.semilogy(t[1::stride], drift_norm[1::stride] + 1e-18, lw=0.6, label="|μ̃|")
    ax.semilogy(t[1::stride], drift_spatial[1::stride] + 1e-18, lw=0.6, label="spatial momentum")
    ax.set_xlabel("t")
    ax.set_ylabel("relative drift")
    ax.set_title("momentum conservation: round-off", fontsize=10)
    ax.legend(fontsize=8)
    I = ", ".join(f"{x:g}" for x in inertia_diag)
    fig.suptitle(
        f"Clebsch–Cayley rigid body (seed 002, Fig. 1): I = ({I}), Δt = {h:g}, t ≤ {t[-1]:g}, {len(mu)} orbits",
        fontsize=12,
    )
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=130)
    return fig
