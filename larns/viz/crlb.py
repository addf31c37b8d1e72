"""The figure of ``larns crlb``: horizontal and vertical CRLB maps side by side (PNG)."""

from __future__ import annotations

import numpy as np


def plot_maps(path, x, y, hz, vt, S, title) -> None:
    """Write the two maps (log colour scale, contour labels in m, stations as red triangles) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    for ax, Z, name in ((axes[0], hz, "horizontal sqrt(var x + var y)"), (axes[1], vt, "vertical sqrt(var z)")):
        Zf = np.where(np.isfinite(Z), Z, np.nan)
        lo = max(np.nanmin(Zf), 1e-2)
        hi = max(np.nanpercentile(Zf, 99), lo * 10)
        im = ax.pcolormesh(x / 1e3, y / 1e3, np.clip(Zf, lo, hi), norm=LogNorm(lo, hi), shading="auto", cmap="viridis")
        levels = [v for v in (1, 2, 3, 5, 10, 20, 50, 100, 200, 500, 1000) if lo < v < hi]
        if levels:
            cs = ax.contour(x / 1e3, y / 1e3, Zf, levels=levels, colors="w", linewidths=0.6)
            ax.clabel(cs, fmt="%g m", fontsize=7)
        ax.plot(S[:, 0] / 1e3, S[:, 1] / 1e3, "r^", ms=7)
        for i, s in enumerate(S):
            ax.annotate(f"{i + 1} ({s[2]:.0f} m)", (s[0] / 1e3, s[1] / 1e3), fontsize=7, color="w")
        fig.colorbar(im, ax=ax, label="m")
        ax.set_title(f"CRLB {name}", fontsize=10)
        ax.set_xlabel("x, km (network frame)")
        ax.set_ylabel("y, km")
        ax.set_aspect("equal")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
