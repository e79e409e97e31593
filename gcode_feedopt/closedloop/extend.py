"""Write a diagnosis into a profile that ``optimize`` uses.

The twin (and so every optimizer method) sees an axis only through its FRF set, so the
effects that are *linear* in the command go into the FRF rows themselves — no schema change,
and every consumer of the profile uses the extended model at once:

- ``delay`` (d): H'(f) = H(f)·e^{−j2πfd};
- ``gain`` (s): H'(f) = s·H(f) (in the twin's coordinates, deviations from the first
  commanded sample; the constant (s−1)·x_0 offset moves the whole part and no contour);
- ``resonance_shift`` (f1): H'(f) = H(f·f0/f1), f0 the twin's dominant mode, interpolated in
  magnitude and unwrapped phase on the same grid (outside the grid: the edge value).

The other kinds (periodic_time/position, backlash, friction, cross_coupling) are not a
commanded→actual FRF; they are recorded in ``provenance["closed_loop"]`` with their
parameters but the optimizer's predictor does not use them yet (stated in docs/diagnose.md).
"""

from __future__ import annotations

import dataclasses
import datetime

import numpy as np

from ..vm import effects as fx

LINEAR_KINDS = ("delay", "gain", "resonance_shift")


def _shift_rows(freq_hz, rows, ratio):
    """rows (N, F) complex -> H(f / ratio) per row (mode f0 -> ratio·f0)."""
    f_src = freq_hz / ratio
    out = np.empty_like(rows)
    for i, h in enumerate(rows):
        mag = np.interp(f_src, freq_hz, np.abs(h))
        ph = np.interp(f_src, freq_hz, np.unwrap(np.angle(h)))
        out[i] = mag * np.exp(1j * ph)
    return out


def extend_profile(profile, effects: list[dict], *, source: str = "", mode_hz: dict | None = None):
    """A copy of ``profile`` with the linear ``effects`` (diagnose's dicts) folded into the
    FRF rows and every effect recorded in provenance. ``mode_hz``: axis -> the twin's
    dominant mode (for resonance_shift; default from the twin's mean impulse response)."""
    from .diagnose import nominal_impulse

    axes = dict(profile.axes)
    applied, recorded = [], []
    for e in effects:
        kind, ax, p = e["kind"], e["axis"], e["params"]
        if kind == "none":
            continue
        if kind not in LINEAR_KINDS:
            recorded.append(e)
            continue
        am = axes[ax]
        f = np.asarray(am.frf.freq_hz, float)
        rows = np.asarray(am.frf.response, complex)
        if kind == "delay":
            rows = rows * np.exp(-2j * np.pi * f * p["delay_s"])[None, :]
        elif kind == "gain":
            rows = rows * p["scale"]
        else:
            if mode_hz and ax in mode_hz:
                f0 = mode_hz[ax]
            else:
                f0 = fx.dominant_mode_hz(nominal_impulse(profile)[ax][0], profile.ts_s)
            rows = _shift_rows(f, rows, p["frequency_hz"] / f0)
        frf = dataclasses.replace(am.frf, response=rows)
        axes[ax] = dataclasses.replace(am, frf=frf)
        applied.append(e)
    prov = dict(profile.provenance)
    hist = list(prov.get("closed_loop", []))
    hist.append({"diagnosed_from": source,
                 "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                 "folded_into_frf": _plain(applied), "recorded_not_modelled": _plain(recorded)})
    prov["closed_loop"] = hist
    return dataclasses.replace(profile, axes=axes, provenance=prov)


def _plain(effects):
    return [{"kind": e["kind"], "axis": e["axis"],
             "params": {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                        for k, v in e["params"].items()}} for e in effects]
