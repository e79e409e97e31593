"""Write sample_gcode/butterfly.gcode: the butterfly NURBS of ../shared/data/butterfly_nurbs.json
placed on an Ender 3 bed, as one extruded layer of G1 moves (chord error <= 1 µm).

    python sample_gcode/make_butterfly.py [path/to/butterfly_nurbs.json] [out.gcode]

The curve is evaluated exactly (scipy's B-spline on homogeneous coordinates), then sampled so
that no chord deviates from the curve by more than CHORD_TOL_MM (checked on a 10x finer
parameter grid). Air-printing and printing both work: E follows a 0.4 mm x 0.2 mm bead.
"""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from gcode_feedopt.plan.curves import nurbs_curve

HERE = pathlib.Path(__file__).resolve().parent
DEFAULT_JSON = HERE.parent.parent / "shared" / "data" / "butterfly_nurbs.json"
CHORD_TOL_MM = 0.001
BED_CENTRE_MM = (117.5, 117.5)
LAYER_MM = 0.2
WIDTH_MM = 0.4
FILAMENT_MM = 1.75
FEED_MM_MIN = 1800  # the slicer-style feed: 30 mm/s


def sample_curve(curve, u0, u1, tol):
    """Parameters whose chords stay within ``tol`` of the curve (adaptive bisection)."""
    us = [u0, u1]
    for _ in range(40):
        u = np.asarray(us)
        mid = 0.5 * (u[:-1] + u[1:])
        a, b = curve(u[:-1]), curve(u[1:])
        d = b - a
        n = np.linalg.norm(d, axis=1)
        cross = np.zeros(len(mid))
        # distance of interior points to the chord (several, so near-cusps are not missed)
        for f in (0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875):
            m = curve(u[:-1] + f * (u[1:] - u[:-1]))
            cross = np.maximum(cross, np.abs(d[:, 0] * (m - a)[:, 1] - d[:, 1] * (m - a)[:, 0])
                               / np.where(n > 0, n, 1))
        bad = cross > tol / 2
        if not bad.any():
            break
        new = []
        for k in range(len(us) - 1):
            new.append(us[k])
            if bad[k]:
                new.append(mid[k])
        new.append(us[-1])
        us = new
    return np.asarray(us)


def main(argv):
    src = pathlib.Path(argv[1]) if len(argv) > 1 else DEFAULT_JSON
    out = pathlib.Path(argv[2]) if len(argv) > 2 else HERE / "butterfly.gcode"
    data = json.loads(src.read_text())
    curve, u0, u1 = nurbs_curve(data)
    u = sample_curve(curve, u0, u1, CHORD_TOL_MM)
    pts = curve(u)
    # check the chord error on a 10x finer grid
    fine = np.linspace(u0, u1, 10 * len(u))
    fp = curve(fine)
    seg = np.clip(np.searchsorted(u, fine, side="right") - 1, 0, len(u) - 2)
    a, b = pts[seg], pts[seg + 1]
    d = b - a
    n = np.linalg.norm(d, axis=1)
    err = np.abs(d[:, 0] * (fp - a)[:, 1] - d[:, 1] * (fp - a)[:, 0]) / np.where(n > 0, n, 1)
    centre = 0.5 * (pts.min(0) + pts.max(0))
    pts = pts - centre + np.asarray(BED_CENTRE_MM)
    e_per_mm = WIDTH_MM * LAYER_MM / (np.pi * (FILAMENT_MM / 2) ** 2)
    lines = [
        "; butterfly NURBS contouring benchmark (Hu et al. 2023), one layer, Ender 3 bed",
        f"; made by sample_gcode/make_butterfly.py from {src.name}; {len(pts) - 1} chords, "
        f"max chord error {err.max() * 1000:.3f} um (limit {CHORD_TOL_MM * 1000:g} um)",
        f"; curve length {np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)):.3f} mm",
        "G21 ; millimetres", "G90 ; absolute XYZ", "M82 ; absolute E", "G92 E0",
        f"G0 X{pts[0, 0]:.4f} Y{pts[0, 1]:.4f} Z{LAYER_MM:.3f} F6000",
        f"G1 F{FEED_MM_MIN}",
    ]
    e = 0.0
    for k in range(1, len(pts)):
        e += e_per_mm * float(np.linalg.norm(pts[k] - pts[k - 1]))
        lines.append(f"G1 X{pts[k, 0]:.4f} Y{pts[k, 1]:.4f} E{e:.5f}")
    lines += [f"G1 Z{LAYER_MM + 5:.3f} F600 ; lift", "M84 ; motors off", ""]
    out.write_text("\n".join(lines))
    print(f"{out}: {len(pts) - 1} moves, max chord error {err.max() * 1000:.3f} um")


if __name__ == "__main__":
    main(sys.argv)
