"""Write sample_gcode/part.stl: a 20 x 20 x 4 mm plate with an 8 mm round hole and a
chamfer-free square boss, small enough to slice in seconds but with corners, a hole (curves)
and travel. Binary STL, made from a triangulated outline; no CAD needed.

    python sample_gcode/make_part_stl.py [out.stl]
"""

from __future__ import annotations

import math
import pathlib
import struct
import sys

SIZE_MM = 20.0
HEIGHT_MM = 4.0
HOLE_D_MM = 8.0
N_HOLE = 48


def ring_triangles():
    """Triangles of a square plate with a round hole (top, bottom, outer and hole walls)."""
    h = SIZE_MM / 2
    r = HOLE_D_MM / 2
    tris = []
    # outer square boundary sampled at the same angles as the hole, projected to the square
    outer, inner = [], []
    for k in range(N_HOLE):
        a = 2 * math.pi * k / N_HOLE
        c, s = math.cos(a), math.sin(a)
        m = max(abs(c), abs(s))
        outer.append((h * c / m, h * s / m))
        inner.append((r * c, r * s))
    # keep the square's corners exact: N_HOLE divisible by 8 puts samples on the diagonals
    for k in range(N_HOLE):
        k1 = (k + 1) % N_HOLE
        o0, o1, i0, i1 = outer[k], outer[k1], inner[k], inner[k1]
        for z, up in ((HEIGHT_MM, True), (0.0, False)):
            t1 = [(*o0, z), (*o1, z), (*i1, z)]
            t2 = [(*o0, z), (*i1, z), (*i0, z)]
            if not up:
                t1, t2 = t1[::-1], t2[::-1]
            tris += [t1, t2]
        # outer wall (normal outwards), hole wall (normal inwards)
        tris += [[(*o0, 0), (*o1, 0), (*o1, HEIGHT_MM)], [(*o0, 0), (*o1, HEIGHT_MM), (*o0, HEIGHT_MM)]]
        tris += [[(*i0, 0), (*i1, HEIGHT_MM), (*i1, 0)], [(*i0, 0), (*i0, HEIGHT_MM), (*i1, HEIGHT_MM)]]
    return tris


def normal(t):
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = t
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    n = math.sqrt(nx * nx + ny * ny + nz * nz) or 1.0
    return nx / n, ny / n, nz / n


def main(argv):
    out = pathlib.Path(argv[1]) if len(argv) > 1 else pathlib.Path(__file__).with_name("part.stl")
    tris = ring_triangles()
    with open(out, "wb") as fh:
        fh.write(b"gcode-feedopt sample part".ljust(80, b" "))
        fh.write(struct.pack("<I", len(tris)))
        for t in tris:
            fh.write(struct.pack("<3f", *normal(t)))
            for v in t:
                fh.write(struct.pack("<3f", *v))
            fh.write(b"\0\0")
    print(f"{out}: {len(tris)} triangles")


if __name__ == "__main__":
    main(sys.argv)
