#!/usr/bin/env python3
"""Progressive cuts whose blade turns: how often the cut stays closed (a scan, not a test).

    python tools/cut_turns.py [-o out/cut_turns] [--paths 40] [--turns 1] [--seed 0]

A vertical blade cuts through a plate of 8 x 8 x 1 cells (80 x 80 x 10 mm) along a random
path from one side to the other with ``--turns`` turns, as a progressive cut in the rest
configuration (:meth:`wcut.cut.Cutter.cut` with ``progressive`` and ``rest``), one or two
increments per leg, compiled and Python operators alternately. Per path it reports:

- ``crossing_edges``: mesh edges that cross the swept surface after the cut. Each edge is
  shortened by ``SHRINK`` of its length at both ends before the test, so that an edge from a
  vertex on one sheet of a turning cut across the other sheet counts (the crossing contract
  of :mod:`wcut.cut.surface` ignores every segment with an endpoint on the surface, which
  hides exactly those);
- ``pieces``: connected components with more than 1 % of the volume (2 is right for a path
  that does not cross itself), and ``crumbs``: the smaller ones.

Writes ``<output>.csv`` and prints the counts. A path with two or more turns may cross itself
(more pieces are then right); the CSV gives the path to tell.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from wcut.cut import Cutter
from wcut.cut.surface import TriangleSurface, joined, strip
from wcut.io import atomic_path
from wcut.mesh import beam
from wcut.topology import TetTopology, check_topology, connected_components

PLATE_CELLS = (8, 8, 1)
PLATE_SIZE = (0.08, 0.08, 0.01)
#: fraction of an edge's length cut off both its ends before the crossing test
SHRINK = 1e-3
#: a component with at most this fraction of the volume is a crumb
CRUMB_FRACTION = 0.01


def blade(x: float, y: float) -> np.ndarray:
    """The blade's two ends (m) at plate position (x, y): through the plate's thickness."""
    return np.array([[x, y, -0.01], [x, y, 0.02]])


def random_paths(count: int, turns: int, seed: int) -> list[tuple[list, bool, int]]:
    """``count`` (path, compiled, increments per leg): paths (m) from x = -5 mm to 85 mm with
    ``turns`` random turning points inside the plate."""
    rng = np.random.default_rng(seed)
    paths = []
    for k in range(count):
        inner = [tuple(rng.uniform(0.015, 0.065, 2).tolist()) for _ in range(turns)]
        path = [(-0.005, float(rng.uniform(0.02, 0.06)))] + inner + [(0.085, float(rng.uniform(0.02, 0.06)))]
        paths.append((path, bool(k % 2), int(rng.integers(1, 3))))
    return paths


def cut_along(path, compiled: bool, increments: int) -> tuple[TetTopology, TriangleSurface]:
    """Cut a fresh plate along ``path`` in ``increments`` increments per leg, checking the mesh
    after each; returns the topology and the whole swept surface."""
    plate = beam(*PLATE_CELLS, size=PLATE_SIZE)
    topo = TetTopology(plate)
    cutter = Cutter(topo, method="paulus", epsilon=0.1, compiled=compiled)
    stops = [np.asarray(path[0], float)]
    for a, b in zip(path, path[1:]):
        stops += [(1 - s) * np.asarray(a) + s * np.asarray(b) for s in np.linspace(0, 1, increments + 1)[1:]]
    swept = []
    for p, q in zip(stops, stops[1:]):
        increment = strip(blade(*p), blade(*q))
        swept.append(increment)
        cutter.cut(increment, progressive=True, rest=True)
        check_topology(topo, plate.volumes().sum())
    return topo, joined(swept)


def crossing_edges(mesh, surface: TriangleSurface, tol: float = 1e-9) -> int:
    """Edges of ``mesh`` (rest positions) crossing ``surface``, each shortened by ``SHRINK``."""
    edges = mesh.edges()
    a, b = mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]]
    t, _ = surface.crossings(a + SHRINK * (b - a), b - SHRINK * (b - a), tol)
    return int(np.isfinite(t).sum())


def scan(count: int, turns: int, seed: int) -> list[dict]:
    rows = []
    for path, compiled, increments in random_paths(count, turns, seed):
        topo, surface = cut_along(path, compiled, increments)
        mesh = topo.to_mesh()
        labels = connected_components(mesh)
        volumes = np.bincount(labels, weights=mesh.volumes())
        fractions = volumes / volumes.sum()
        rows.append({"path_mm": " ".join(f"{1e3 * x:.2f},{1e3 * y:.2f}" for x, y in path), "compiled": compiled,
                     "increments_per_leg": increments, "crossing_edges": crossing_edges(mesh, surface),
                     "pieces": int((fractions > CRUMB_FRACTION).sum()),
                     "crumbs": int((fractions <= CRUMB_FRACTION).sum())})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="out/cut_turns", help="output stem (.csv)")
    parser.add_argument("--paths", type=int, default=40)
    parser.add_argument("--turns", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.paths < 1 or args.turns < 0:
        parser.error("--paths must be at least 1 and --turns at least 0")
    rows = scan(args.paths, args.turns, args.seed)
    out = Path(args.output).with_suffix(".csv")
    with atomic_path(out) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    closed = sum(r["crossing_edges"] > 0 for r in rows)
    whole = sum(r["pieces"] != 2 for r in rows)
    crumbly = sum(r["crumbs"] > 0 for r in rows)
    print(f"{len(rows)} paths, {args.turns} turn(s): {closed} with edges across the cut, "
          f"{whole} not in two pieces, {crumbly} with crumbs; {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
