"""Write a diagnosis into a profile that ``optimize`` uses.

The twin (and so every optimizer method) sees an axis through its physics, built by
``twin.physics`` from the axis's FRF set. The effects that are *linear* in the command are
stored as the axis's extensions (``axes.<axis>.effects`` in the YAML) and applied to every
fitted model of the axis, so every consumer of the profile uses the extended model at once:

- ``delay`` (delay_s): the response delay_s later;
- ``gain`` (scale): the response times scale (in the twin's coordinates, deviations from the
  first commanded sample; the constant (s−1)·x_0 offset moves the whole part and no contour);
- ``resonance_shift`` (frequency_hz): the dominant mode moved there as a mass change moves it.

The other kinds (periodic_time/position, backlash, friction, cross_coupling) are not a
commanded→actual linear response; they are recorded in ``provenance["closed_loop"]`` with their
parameters but the optimizer's predictor does not use them yet (stated in docs/diagnose.md).
"""

from __future__ import annotations

import dataclasses
import datetime

import numpy as np

LINEAR_KINDS = ("delay", "gain", "resonance_shift")


def extend_profile(profile, effects: list[dict], *, source: str = "", mode_hz: dict | None = None):
    """A copy of ``profile`` with the linear ``effects`` (diagnose's dicts) added to the axes'
    extensions and every effect recorded in provenance. ``mode_hz`` is accepted for
    compatibility and unused: a resonance shift moves the fitted dominant mode."""
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
        params = {k: float(v) for k, v in p.items()
                  if k in ("delay_s", "scale", "frequency_hz")}
        axes[ax] = dataclasses.replace(am, effects=tuple(am.effects) + ({"kind": kind, "params": params},))
        applied.append(e)
    prov = dict(profile.provenance)
    hist = list(prov.get("closed_loop", []))
    hist.append({"diagnosed_from": source,
                 "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                 "applied_to_the_model": _plain(applied), "recorded_not_modelled": _plain(recorded)})
    prov["closed_loop"] = hist
    return dataclasses.replace(profile, axes=axes, provenance=prov)


def _plain(effects):
    return [{"kind": e["kind"], "axis": e["axis"],
             "params": {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                        for k, v in e["params"].items()}} for e in effects]
