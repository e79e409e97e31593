"""Write a diagnosis into a profile that ``predict``, ``learn`` and ``optimize`` use.

Every named effect is written with the parameters ``diagnose`` fitted (weights and signs as
fitted: a friction lag of −0.3 µm is written as −0.3 µm, not as a unit effect) into the axis's
extensions, ``axes.<axis>.effects`` in the YAML:

- ``delay`` (seconds → ``delay_s``), ``gain`` (``scale``), ``resonance_shift``
  (``frequency_hz``) change the axis's physics: ``twin.physics.apply_effects`` applies them to
  every modal fit, so every consumer of the profile (twin, optimizer, virtual machine) uses the
  extended response;
- ``periodic_position``, ``backlash``, ``friction``, ``cross_coupling`` add a deterministic term
  to the twin's mean prediction (``twin.extensions.mean_offsets``, used by ``predict`` and
  ``learn``); the slow-down optimizer adds ``cross_coupling``'s
  (``twin.extensions.motion_offsets``), not the others (docs/diagnose.md, *Not done*);
- ``periodic_time`` (a fan, no phase kept from print to print) adds A²/2 to the prediction's
  variance.

``diagnose_log`` computes its held-out "after" RMS from the profile this module writes, so the
two agree by construction; tests/closedloop/test_extend.py checks it through the YAML file.
"""

from __future__ import annotations

import dataclasses
import datetime

import numpy as np

from ..twin.extensions import LINEAR_KINDS, PARAMS

#: diagnose's parameter names -> the profile's
_RENAME = {"delay": {"seconds": "delay_s"}}


def profile_effect(effect: dict) -> dict:
    """diagnose's effect dict -> the profile's ``{"kind", "params"}`` (fitted values kept)."""
    kind = effect["kind"]
    ren = _RENAME.get(kind, {})
    params = {}
    for k, v in effect["params"].items():
        k = ren.get(k, k)
        if k not in PARAMS[kind]:
            continue
        params[k] = v if isinstance(v, str) else float(v)
    return {"kind": kind, "params": params}


def extend_profile(profile, effects: list[dict], *, source: str = ""):
    """A copy of ``profile`` with every named effect (diagnose's dicts) added to its axis's
    extensions and recorded in provenance."""
    axes = dict(profile.axes)
    applied = []
    for e in effects:
        kind, ax = e["kind"], e["axis"]
        if kind == "none":
            continue
        pe = profile_effect(e)
        am = axes[ax]
        axes[ax] = dataclasses.replace(am, effects=tuple(am.effects) + (pe,))
        applied.append({"kind": kind, "axis": ax, "params": pe["params"],
                        "changes": "physics" if kind in LINEAR_KINDS else
                        ("variance" if kind == "periodic_time" else "mean")})
    prov = dict(profile.provenance)
    hist = list(prov.get("closed_loop", []))
    hist.append({"diagnosed_from": source,
                 "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                 "applied_to_the_model": _plain(applied)})
    prov["closed_loop"] = hist
    return dataclasses.replace(profile, axes=axes, provenance=prov)


def _plain(effects):
    return [{"kind": e["kind"], "axis": e["axis"], "changes": e["changes"],
             "params": {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                        for k, v in e["params"].items()}} for e in effects]
