#!/usr/bin/env python3
"""The opening of an incision at one point of its line, measured in a
cutsim-server state file (`--out FILE.vtu`: world positions, displacements
from rest, tets, each tet's count of faces a cut opened).

    incision_gap.py FILE.vtu --at X Y Z --along X Y Z [--normal X Y Z] [--half-width M]

The wound's lips at the point AT of the planned line (rest frame, m): the
nodes of tets with an opened face that lie on the surface at rest (within
0.1 mm of AT's level along NORMAL, default +z) and within HALF-WIDTH
(default 1.5 mm) of AT along the line. Each node's side of the line is the
side of the mean rest centroid of its tets (a node the cut split has a
copy on each side). The gap is the distance across the line, in the world,
between the nearest lip nodes of the two sides. Prints one JSON line
{"gap_m", "lips_minus", "lips_plus"}; exits 1 when a side has no lip node
(no opened face there), 2 on a file it cannot read.
"""
import argparse
import json
import re
import sys


def data_array(text, name):
    """The numbers of the DataArray called NAME (the first one)."""
    m = re.search(r'<DataArray[^>]*Name="%s"[^>]*>(.*?)</DataArray>' % re.escape(name), text, re.S)
    if not m:
        raise ValueError(f"no DataArray {name}")
    return [float(v) for v in m.group(1).split()]


def points(text):
    m = re.search(r'<Points>\s*<DataArray[^>]*>(.*?)</DataArray>', text, re.S)
    if not m:
        raise ValueError("no <Points>")
    return [float(v) for v in m.group(1).split()]


def triples(values):
    return [tuple(values[i:i + 3]) for i in range(0, len(values), 3)]


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def unit(a):
    n = dot(a, a) ** 0.5
    return tuple(x / n for x in a)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("vtu")
    ap.add_argument("--at", type=float, nargs=3, required=True)
    ap.add_argument("--along", type=float, nargs=3, required=True)
    ap.add_argument("--normal", type=float, nargs=3, default=(0.0, 0.0, 1.0))
    ap.add_argument("--half-width", type=float, default=0.0015)
    a = ap.parse_args()
    try:
        with open(a.vtu, encoding="utf-8") as f:
            text = f.read()
        world = triples(points(text))
        displacement = triples(data_array(text, "displacement"))
        conn = [int(v) for v in data_array(text, "connectivity")]
        cut_faces = data_array(text, "cut_faces")
    except (OSError, ValueError) as e:
        print(f"incision_gap: {a.vtu}: {e}", file=sys.stderr)
        return 2
    rest = [tuple(w - d for w, d in zip(wp, dp)) for wp, dp in zip(world, displacement)]
    tets = [conn[i:i + 4] for i in range(0, len(conn), 4)]
    at, along, normal = tuple(a.at), unit(a.along), unit(a.normal)
    across = unit(cross(normal, along))
    rel = lambda p: tuple(x - y for x, y in zip(p, at))
    side = [0.0] * len(world)
    lips = set()
    for t, tet in enumerate(tets):
        centroid = tuple(sum(rest[n][k] for n in tet) / 4 for k in range(3))
        s = dot(rel(centroid), across)
        for n in tet:
            side[n] += s
        if cut_faces[t] > 0:
            lips.update(tet)
    minus, plus = [], []
    for n in lips:
        r = rel(rest[n])
        if abs(dot(r, normal)) > 1e-4 or abs(dot(r, along)) > a.half_width:
            continue
        (minus if side[n] < 0 else plus).append(dot(rel(world[n]), across))
    if not minus or not plus:
        print(json.dumps({"gap_m": None, "lips_minus": len(minus), "lips_plus": len(plus)}))
        return 1
    print(json.dumps({"gap_m": min(plus) - max(minus), "lips_minus": len(minus), "lips_plus": len(plus)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
