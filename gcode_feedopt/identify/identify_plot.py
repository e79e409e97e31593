"""PNG of fitted modal model against the data, one panel per axis (matplotlib only here)."""

from __future__ import annotations

import numpy as np


def plot_fits(path, panels: dict) -> None:
    """``panels``: axis -> list of (label, freq_hz (K,), data |H| (K,), model |H| (K,))."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(len(panels), 1, figsize=(7, 3.2 * len(panels)), squeeze=False)
    for ax, (axis, curves) in zip(axs[:, 0], panels.items()):
        for label, f, data, model in curves:
            line, = ax.semilogy(f, data, ".", ms=3, label=f"{label} data")
            ax.semilogy(f, model, "-", color=line.get_color(), label=f"{label} fit")
        ax.set_title(f"axis {axis}: |H| (commanded -> actual), fit vs data")
        ax.set_xlabel("frequency, Hz")
        ax.set_ylabel("|H|")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
