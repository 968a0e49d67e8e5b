"""Figures of the stability study (``benchmarks/stability.py``): energy-error maps over (h, |ω₀|)
with failures marked, and the long runs' error growth."""

from pathlib import Path

import numpy as np


def plot_maps(results, out_dir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    markers = {1: ("x", "Newton max it."), 2: ("+", "non-finite"), 3: ("o", "exp singular"), 4: ("s", "diffrax failed")}
    paths = []
    for kind, per_scheme in results.items():
        schemes = list(per_scheme)
        ncol = min(4, len(schemes))
        nrow = -(-len(schemes) // ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(4 * ncol, 3.4 * nrow), squeeze=False, sharex=True, sharey=True)
        for ax, scheme in zip(axes.flat, schemes):
            m = per_scheme[scheme]["map"]
            n_spin, n_h = len(m["spin"]), len(m["hw"])
            H, S = m["h"].reshape(n_spin, n_h), np.repeat(m["spin"], n_h).reshape(n_spin, n_h)
            err = np.log10(np.clip(m["energy"], 1e-16, 1e3)).reshape(n_spin, n_h)
            im = ax.scatter(H, S, c=err, marker="s", s=60, cmap="viridis", vmin=-16, vmax=3)
            code = m["code"].reshape(n_spin, n_h)
            for c, (mk, label) in markers.items():
                sel = code == c
                if sel.any():
                    ax.scatter(H[sel], S[sel], marker=mk, c="red", s=14, label=label)
            spins = np.asarray(m["spin"])
            for k, style in ((np.pi, "--"), (2 * np.pi, ":")):
                ax.plot(k / spins, spins, "w" + style, lw=1)
            ax.set(xscale="log", yscale="log", title=scheme)
            ax.set_xlim(H.min() / 2, H.max() * 2)
            if ax in axes[:, 0]:
                ax.set_ylabel("spin rate |ω₀| [rad/s]")
            if ax in axes[-1]:
                ax.set_xlabel("h [s]")
            if any((code == c).any() for c in markers):
                ax.legend(fontsize=6, loc="lower left")
        for ax in axes.flat[len(schemes):]:
            ax.axis("off")
        fig.colorbar(im, ax=axes, label="log10 max |E/E₀ − 1|")
        fig.suptitle(f"{kind}, {results[kind][schemes[0]]['map_steps']} steps: energy error, failures"
                     " (white: |hω| = π dashed, 2π dotted)")
        path = Path(out_dir) / f"stability_{kind}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(str(path))
    return paths


def plot_long(long_runs, out_dir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for label, run in long_runs.items():
        steps = np.asarray(run["steps"][1:])
        for ax, key in zip(axes, ("energy_error", "kelvin_noether_error")):
            ax.loglog(steps, np.maximum(np.asarray(run[key][1:]), 1e-18), label=label, lw=0.8)
    axes[0].set(xlabel="steps", ylabel="|E/E₀ − 1|", title="energy")
    axes[1].set(xlabel="steps", ylabel="|ΔKN| / scale", title="Kelvin–Noether")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    path = Path(out_dir) / "stability_long.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)
