"""Slicer feature tags (``;TYPE:...``) and the canonical features a tolerance is set for.

Cura writes ``;TYPE:WALL-OUTER``, PrusaSlicer/OrcaSlicer/SuperSlicer ``;TYPE:External perimeter``
(Orca: ``; FEATURE: Outer wall``). :data:`TAG_TO_FEATURE` is the one table that maps every tag
we know to one of :data:`FEATURES`; a tag not in it maps to ``other`` (and is counted, so the
summary can say so). Moves without XY extrusion (travel, retract, Z hop) are ``travel``
whatever the tag says. A file without tags (hand-written Klipper/Marlin, CNC) has every
extruding move ``""`` (untagged): it falls back to the single tolerance.
"""

from __future__ import annotations

import numpy as np

from ..errors import FeedOptError

#: the canonical features, in report order
FEATURES = ("outer_wall", "inner_wall", "skin", "infill", "bridge", "support", "skirt",
            "travel", "other")

#: slicer tag (upper case, stripped) -> canonical feature
TAG_TO_FEATURE = {
    # Cura
    "WALL-OUTER": "outer_wall", "WALL-INNER": "inner_wall", "SKIN": "skin", "FILL": "infill",
    "SUPPORT": "support", "SUPPORT-INTERFACE": "support", "SUPPORT-INFILL": "support",
    "SKIRT": "skirt", "PRIME-TOWER": "other", "BRIDGE": "bridge",
    # PrusaSlicer / SuperSlicer
    "EXTERNAL PERIMETER": "outer_wall", "PERIMETER": "inner_wall",
    "OVERHANG PERIMETER": "outer_wall", "INTERNAL INFILL": "infill", "SOLID INFILL": "skin",
    "TOP SOLID INFILL": "skin", "BRIDGE INFILL": "bridge", "INTERNAL BRIDGE INFILL": "bridge",
    "GAP FILL": "inner_wall", "SKIRT/BRIM": "skirt", "SKIRT": "skirt", "BRIM": "skirt",
    "SUPPORT MATERIAL": "support", "SUPPORT MATERIAL INTERFACE": "support",
    "WIPE TOWER": "other", "IRONING": "skin", "CUSTOM": "other",
    # OrcaSlicer / Bambu Studio
    "OUTER WALL": "outer_wall", "INNER WALL": "inner_wall", "OVERHANG WALL": "outer_wall",
    "SPARSE INFILL": "infill", "INTERNAL SOLID INFILL": "skin", "TOP SURFACE": "skin",
    "BOTTOM SURFACE": "skin", "SUPPORT INTERFACE": "support", "SUPPORT TRANSITION": "support",
    "PRIME TOWER": "other",
}

#: comment prefixes that carry a feature tag (upper case, after the ``;``)
TAG_PREFIXES = ("TYPE:", " FEATURE:", "FEATURE:")


def tag_of(text: str) -> str | None:
    """The feature tag of a comment line (``;TYPE:SKIN`` -> ``SKIN``), else None."""
    t = text.lstrip()
    if not t.startswith(";"):
        return None
    body = t[1:]
    up = body.upper()
    for p in TAG_PREFIXES:
        if up.startswith(p):
            return body[len(p):].strip().upper()
    return None


def canonical(tag: str) -> str:
    """The canonical feature of a slicer tag ("" stays "": untagged)."""
    if not tag:
        return ""
    return TAG_TO_FEATURE.get(tag.strip().upper(), "other")


def move_feature(kind: str, tag: str) -> str:
    """The feature of one move: ``travel`` for a move that does not extrude, else its tag's."""
    if kind != "extrude":
        return "travel"
    return canonical(tag)


#: ``--feature-tolerance defaults``: visible walls tightest, hidden infill and support buy
#: the time (features not named keep the scalar --tolerance; travel has none)
DEFAULT_FEATURE_TOLERANCE = {"outer_wall": 0.05, "inner_wall": 0.1, "skin": 0.1,
                             "bridge": 0.1, "infill": 0.3, "support": 0.3, "skirt": 0.3}


def parse_feature_tolerance(text: str | None) -> dict[str, float] | None:
    """``outer_wall=0.05,infill=0.3`` -> {feature: mm}; ``defaults`` ->
    :data:`DEFAULT_FEATURE_TOLERANCE` (items after it override); ``off`` -> {} (one
    tolerance, the profile's table ignored); None -> None. A FeedOptError (one line) for an
    unknown feature or a value that is not a positive number (``none``: no limit)."""
    if text is None:
        return None
    if text.strip().lower() == "off":
        return {}
    out: dict[str, float] = {}
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        if part.lower() == "defaults":
            out.update(DEFAULT_FEATURE_TOLERANCE)
            continue
        if "=" not in part:
            raise FeedOptError(f"--feature-tolerance: '{part}' is not FEATURE=MM "
                               f"(e.g. outer_wall=0.05,infill=0.3)")
        k, v = (x.strip() for x in part.split("=", 1))
        out[k] = _value(k, v)
    check_feature_tolerance(out)
    return out


def _value(k: str, v) -> float:
    if isinstance(v, str) and v.strip().lower() in ("none", "inf", "off"):
        return float("inf")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise FeedOptError(f"feature tolerance {k}={v!r}: not a number of mm") from None
    if not x > 0:
        raise FeedOptError(f"feature tolerance {k}={v!r}: must be positive mm (or 'none')")
    return x


def check_feature_tolerance(tol: dict) -> dict[str, float]:
    """Validate {feature: mm}: known feature names, positive values; returns floats."""
    out = {}
    for k, v in tol.items():
        if k not in FEATURES:
            raise FeedOptError(f"unknown feature '{k}' in feature tolerance; known: "
                               f"{', '.join(FEATURES)}")
        out[k] = _value(k, v)
    return out


def segment_features(path, program) -> np.ndarray:
    """(N,) feature name of each path segment (from its move)."""
    feats = np.array([getattr(m, "feature", "") for m in program.moves] or [""], dtype=object)
    return feats[np.asarray(path.move_index)]


def segment_tolerance(seg_features: np.ndarray, feature_tol: dict,
                      default_mm: float) -> np.ndarray:
    """(N,) tolerance of each segment: its feature's, else ``default_mm`` (untagged moves and
    features not set).

    Travel deposits nothing, so the optimizer constrains no travel sample except the few at
    its ends that still cover an extrusion (optimize.free.ContourRules: the nozzle running
    past a wall's end point); those belong to that extrusion, so a travel segment gets the
    tighter tolerance of the extruding segments before and after it — unless ``travel`` is
    named in ``feature_tol``."""
    tol = np.full(seg_features.size, float(default_mm))
    for f, v in feature_tol.items():
        tol[seg_features == f] = float(v)
    if "travel" not in feature_tol:
        trav = seg_features == "travel"
        if trav.any() and not trav.all():
            idx = np.arange(tol.size)
            prev = np.maximum.accumulate(np.where(trav, -1, idx))
            nxt = np.minimum.accumulate(np.where(trav, tol.size, idx)[::-1])[::-1]
            t_prev = np.where(prev >= 0, tol[np.maximum(prev, 0)], np.inf)
            t_next = np.where(nxt < tol.size, tol[np.minimum(nxt, tol.size - 1)], np.inf)
            tol[trav] = np.minimum(t_prev, t_next)[trav]
    return tol


def present(seg_features: np.ndarray) -> set[str]:
    return {str(f) for f in np.unique(seg_features.astype(str))}
