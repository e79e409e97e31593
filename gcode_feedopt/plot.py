"""Plots for people (the only library module importing matplotlib)."""

from __future__ import annotations

import numpy as np


def plot_run(path, schedule, out_png, *, title: str = "", tolerance_mm: float | None = None,
             predicted_error_mm: np.ndarray | None = None) -> None:
    """XY path coloured by planned speed, and speed (and predicted contour error, when a
    twin-driven method gives it) along time. Writes a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    s = schedule.s_mm
    t = np.arange(s.size) * schedule.ts_s
    v = schedule.speed_mm_s()
    pos = path.position(s)
    # the path of extrusion moves only (travels would hide the part), coloured by speed
    seg = path.segment_at(s)
    extr = path.move_kind[seg] == 0
    pts = pos[:, :2]
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    keep = extr[1:] & extr[:-1] & (np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1) < 5.0)
    rows = 3 if predicted_error_mm is not None else 2
    fig = plt.figure(figsize=(11, 8.5), constrained_layout=True)
    gs = fig.add_gridspec(rows, 2, width_ratios=[1.2, 1])
    ax = fig.add_subplot(gs[:, 0])
    lc = LineCollection(segs[keep], array=v[1:][keep], cmap="viridis", linewidths=0.8)
    ax.add_collection(lc)
    if keep.any():
        xy = segs[keep].reshape(-1, 2)
        ax.set_xlim(xy[:, 0].min() - 2, xy[:, 0].max() + 2)
        ax.set_ylim(xy[:, 1].min() - 2, xy[:, 1].max() + 2)
    ax.set_aspect("equal")
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_title("Extrusion path coloured by planned speed")
    fig.colorbar(lc, ax=ax, label="speed (mm/s)", shrink=0.8)
    a1 = fig.add_subplot(gs[0, 1])
    a1.plot(t, v, lw=0.6, color="C0", label="planned speed")
    a1.set_xlabel("time (s)")
    a1.set_ylabel("speed (mm/s)")
    a1.set_title("Feed along the print")
    a1.legend(loc="upper right")
    a2 = fig.add_subplot(gs[1, 1])
    hist_v = v[v > 0.5]
    a2.hist(hist_v, bins=60, weights=np.full(hist_v.size, schedule.ts_s), color="C1",
            label="time spent at each speed")
    a2.set_xlabel("speed (mm/s)")
    a2.set_ylabel("time (s)")
    a2.legend(loc="upper right")
    if predicted_error_mm is not None:
        a3 = fig.add_subplot(gs[2, 1])
        a3.plot(t[:predicted_error_mm.size], predicted_error_mm, lw=0.6, color="C3",
                label="predicted contour error (η-quantile)")
        if tolerance_mm is not None:
            a3.axhline(tolerance_mm, color="k", ls="--", lw=0.8, label="tolerance")
        a3.set_xlabel("time (s)")
        a3.set_ylabel("contour error (mm)")
        a3.legend(loc="upper right")
    if title:
        fig.suptitle(title)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def plot_compare(runs, out_png, *, tolerance_mm: float, title: str = "") -> None:
    """The paper's Fig. 12: feedrate, acceleration, contour error, tolerance violation γ and
    prediction error against time, one colour per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(5, 1, figsize=(11, 12), sharex=True, constrained_layout=True)
    for r in runs:
        s = r.series
        t = s["t_s"]
        label = f"{r.method} ({r.cycle_time_s:.2f} s)"
        axes[0].plot(t, s["feed_mm_s"], lw=0.8, label=label)
        acc = np.hypot(s["acc_x_mm_s2"], s["acc_y_mm_s2"]) / 1000.0
        axes[1].plot(t, acc, lw=0.6)
        eps = s.get("contour_error_mm")
        if eps is not None:
            axes[2].plot(t, eps, lw=0.6)
            axes[3].plot(t, 1000.0 * np.maximum(eps - tolerance_mm, 0.0), lw=0.6)
        if "pred_err_x_mm" in s:
            axes[4].plot(t, np.hypot(s["pred_err_x_mm"], s["pred_err_y_mm"]), lw=0.6)
        else:
            axes[4].plot([], [])
    # a data-only twin starts from a zero prior (it predicts nothing until it has learned):
    # scale the prediction panel to the 99th percentile so the others stay readable
    tops = [np.quantile(np.hypot(r.series["pred_err_x_mm"], r.series["pred_err_y_mm"]), 0.99)
            for r in runs if "pred_err_x_mm" in r.series]
    if tops and max(tops) > 0:
        axes[4].set_ylim(0, 1.2 * max(tops))
    axes[2].axhline(tolerance_mm, color="k", ls="--", lw=0.8)
    axes[0].set_ylabel("feed (mm/s)")
    axes[1].set_ylabel("|acc| (m/s²)")
    axes[2].set_ylabel("contour err (mm)")
    axes[3].set_ylabel("γ (µm)")
    axes[4].set_ylabel("pred. err (mm)")
    axes[4].set_xlabel("time (s)")
    axes[0].legend(fontsize=8, ncol=3)
    if title:
        axes[0].set_title(title)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
