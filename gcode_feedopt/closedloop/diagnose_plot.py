"""PNG of a diagnosis: residual per axis before/after the named effects, and its spectrum
(matplotlib only here, imported lazily, Agg backend as plot.py does)."""

from __future__ import annotations

import numpy as np


def plot_diagnosis(path, diagnosis, ts_s: float, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, c = diagnosis.residual_mm, diagnosis.corrected_mm
    K = r.shape[0]
    t = np.arange(K) * ts_s
    fig, axs = plt.subplots(2, 2, figsize=(11, 6), squeeze=False)
    names = ", ".join(f"{e['kind']}({e['axis']})" for e in diagnosis.effects)
    for i, ax in enumerate("xy"):
        a = axs[i, 0]
        a.plot(t, r[:, i] * 1e3, lw=0.5, label="measured − twin")
        a.plot(t, c[:, i] * 1e3, lw=0.5, label="after extension")
        a.axvline(diagnosis.fit_samples * ts_s, color="k", ls="--", lw=0.8, label="fit | held out")
        a.set_xlabel("t, s")
        a.set_ylabel(f"{ax} residual, µm")
        a.legend(fontsize=7, loc="upper right")
        a.grid(alpha=0.3)
        b = axs[i, 1]
        for sig, lab in ((r[:, i], "before"), (c[:, i], "after")):
            R = np.abs(np.fft.rfft(sig * np.hanning(K))) * 4.0 / K
            f = np.fft.rfftfreq(K, ts_s)
            b.semilogy(f[1:], R[1:] * 1e3 + 1e-6, lw=0.6, label=lab)
        b.set_xlabel("frequency, Hz")
        b.set_ylabel(f"{ax} residual amplitude, µm")
        b.legend(fontsize=7)
        b.grid(alpha=0.3, which="both")
    fig.suptitle(f"{title} — named: {names}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
