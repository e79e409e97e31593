"""Per-stage seconds of the kinematic run (parse, path, plan, write, verify, save).

    python benchmarks/bench_foundation.py [FILE ...]   (default: the Cura Benchy, 95,520 moves)

Prints one row per file; repeat runs to see the spread (the machine is shared).
"""

from __future__ import annotations

import pathlib
import platform
import sys
import tempfile
import time

from gcode_feedopt.pipeline import Options, optimize_file
from gcode_feedopt.profile import load_profile

REPO = pathlib.Path(__file__).resolve().parents[1]
DEFAULT = REPO.parent / "shared" / "data" / "gcode" / "cura-4.11_ender3_3dbenchy.gcode"


def main(argv):
    files = [pathlib.Path(a) for a in argv[1:]] or [DEFAULT]
    prof = load_profile("ender3pro")
    print(f"# {platform.processor() or platform.machine()}, Python {platform.python_version()}")
    print(f"{'file':40s} {'moves':>7s} {'parse':>6s} {'path':>6s} {'plan':>6s} {'write':>6s} "
          f"{'verify':>6s} {'save':>6s} {'total':>6s} {'print':>8s}")
    with tempfile.TemporaryDirectory() as tmp:
        for f in files:
            t0 = time.perf_counter()
            rep = optimize_file(f, pathlib.Path(tmp) / "out.gcode", prof, Options())
            total = time.perf_counter() - t0
            w = rep.stage_wall_s
            print(f"{f.name[:40]:40s} {rep.moves:7d} {w['parse']:6.2f} {w['path']:6.2f} "
                  f"{w['plan']:6.2f} {w['write']:6.2f} {w['verify']:6.2f} {w.get('save', 0):6.2f} "
                  f"{total:6.2f} {rep.output_time_s:8.0f}")


if __name__ == "__main__":
    main(sys.argv)
