#!/usr/bin/env python3
"""Random plane cuts through meshes made by others and through poor meshes: do they separate,
keep the volume and leave well-shaped elements?

For each mesh, ``--cuts`` planes through a random point of the mesh's middle half (by bounding
box) with a random normal are cut, each on a fresh copy, for every method and epsilon asked.
After each cut: the topology is checked from scratch (:func:`wcut.topology.check_topology`),
the cut is judged by :func:`wcut.cut.separation.plane_separation` (pieces as a simulation sees
them), and the volume change, worst dihedral angle and smallest element volume (relative to
the median) are recorded. ``--chain N`` cuts each copy N times in a row instead (planes crossing
earlier cuts).

Run::

    .venv/bin/python tools/cut_separation.py [MESH ...] [--cuts 40] [--chain 1] [--methods paulus bielser]
        [--epsilons 0 0.1] [--seed 0] [--no-improve] [--csv out.csv]

Without meshes: SOFA's in ``../shared/meshes`` where the checkout has them, the project's
organ, and two poor meshes made here (:func:`poor_meshes`).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from wcut.cut import Cutter, Plane  # noqa: E402
from wcut.cut.separation import plane_separation  # noqa: E402
from wcut.errors import WcutError  # noqa: E402
from wcut.mesh import TetMesh, beam, dihedral_angles, perturbed, unique_rows  # noqa: E402
from wcut.topology import TetTopology, check_topology  # noqa: E402


def poor_meshes(seed: int = 0) -> dict:
    """Meshes of poor quality made here: an 8x4x4 beam with its inner vertices moved by up to
    30% and 100% of an edge (:func:`wcut.mesh.perturbed`)."""
    base = beam(8, 4, 4, size=(0.08, 0.04, 0.04))
    return {"beam_perturbed": perturbed(base, 0.3, seed), "beam_slivers": perturbed(base, 1.0, seed)}


def meshes(paths: list[str], seed: int) -> dict:
    found = {}
    shared = ROOT.parent / "shared" / "meshes"
    if not paths:
        paths = [str(p) for p in sorted(shared.glob("*.vt*"))] + [str(ROOT / "scenes/meshes/organ.vtu")]
        found.update(poor_meshes(seed))
    for p in paths:
        found[Path(p).name] = TetMesh.load(p)
    return found


def random_plane(mesh: TetMesh, rng) -> Plane:
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    point = lo + (hi - lo) * rng.uniform(0.25, 0.75, 3)
    normal = rng.normal(size=3)
    return Plane(point, normal)


#: The issue's quality target: after a cut, the worst dihedral angle is at least
#: min(TARGET_DEGREES, half the worst of the mesh it cut).
TARGET_DEGREES = 5.0


def domain_wedge(mesh: TetMesh) -> float:
    """The smallest interior angle (degrees) of the meshed domain at an edge of its boundary:
    the sum of the dihedral angles of the elements around the edge. Every element at that edge
    has a dihedral angle no larger, so no mesh of the same domain can have a better worst
    angle (a plane meeting the boundary, or an earlier cut, at a small angle makes one)."""
    angles = dihedral_angles(mesh.vertices, mesh.tets)
    # dihedral_angles' column k is at the edge of the two corners outside the k-th face pair
    ends = np.array([(2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)])
    edges = np.sort(mesh.tets[:, ends], axis=2).reshape(-1, 2)
    keys, index = unique_rows(edges, mesh.vertex_count, return_inverse=True)
    total = np.bincount(index.ravel(), angles.ravel())
    rims = np.sort(mesh.boundary().triangles[:, [[0, 1], [1, 2], [0, 2]]].reshape(-1, 2), axis=1)
    on_boundary = np.isin(keys @ [mesh.vertex_count, 1], rims @ [mesh.vertex_count, 1])
    return float(total[on_boundary].min())


def one(mesh: TetMesh, planes: list[Plane], method: str, epsilon: float, improve: bool = True) -> dict:
    """Cut a fresh copy of ``mesh`` by ``planes`` in a row. Besides separation, volume and the
    final worst angle and smallest element, counts the cuts that leave the worst dihedral angle
    below min(5 degrees, half the worst of the mesh that cut received) (``misses``), below
    min(5, half the worst of ``mesh``) (``misses_input``), and those of the misses where the
    domain itself has a wedge below the target (``forced``: :func:`domain_wedge`, no mesh of
    it could meet the target). The worst angle of the elements the cuts made (none of
    ``mesh``'s, ``worst_new``) tells what they did to a mesh whose own worst stays."""
    topo = TetTopology(mesh)
    cutter = Cutter(topo, method=method, epsilon=epsilon, improve=improve)
    volume = float(mesh.volumes().sum())
    median = float(np.median(mesh.volumes()))
    record = {"separated": True, "error": "", "valid": True, "misses": 0, "misses_input": 0, "forced": 0}
    worst_input = worst = float(dihedral_angles(mesh.vertices, mesh.tets).min())
    record["worst_new"] = math.inf
    own = {tuple(t) for t in np.sort(mesh.tets, axis=1).tolist()}
    for plane in planes:
        try:
            result = cutter.cut(plane)
        except WcutError as exc:
            record.update(error=str(exc).split("\n")[0][:80])
            return record
        if result.change.is_empty:
            continue
        after = topo.to_mesh()
        try:
            check_topology(topo)
        except Exception as exc:  # noqa: BLE001 - a study records what fails
            record.update(valid=False, error=str(exc)[:80])
        s = plane_separation(after.vertices, after.tets, plane, cutter.tolerance,
                                  mean_edge_length=cutter.mean_edge_length, in_plane=cutter.in_plane)
        record["separated"] &= s.separated
        record["reach"] = max(record.get("reach", 0.0), s.deepest_reach)
        angles = dihedral_angles(after.vertices, after.tets).min(axis=1)
        before, worst = worst, float(angles.min())
        made = [tuple(t) not in own for t in np.sort(after.tets, axis=1).tolist()]
        record["worst_new"] = min(record["worst_new"], float(angles[made].min(initial=math.inf)))
        target = min(TARGET_DEGREES, before / 2)
        if worst < target:
            record["misses"] += 1
            record["forced"] += domain_wedge(after) < target
        record["misses_input"] += worst < min(TARGET_DEGREES, worst_input / 2)
    volumes = after.volumes()
    record.update(volume_change=abs(float(volumes.sum()) - volume) / volume, min_dihedral=worst,
                  min_volume=float(volumes.min()) / median, elements=after.tet_count)
    return record


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="*")
    parser.add_argument("--cuts", type=int, default=40)
    parser.add_argument("--chain", type=int, default=1)
    parser.add_argument("--methods", nargs="+", default=["paulus", "bielser"])
    parser.add_argument("--epsilons", nargs="+", type=float, default=[0.0, 0.1])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-improve", dest="improve", action="store_false",
                        help="no local mesh improvement after each cut (on by default)")
    parser.add_argument("--csv")
    args = parser.parse_args(argv)
    rows = []
    for name, mesh in meshes(args.meshes, args.seed).items():
        rng = np.random.default_rng(args.seed)
        chains = [[random_plane(mesh, rng) for _ in range(args.chain)] for _ in range(args.cuts)]
        worst_in = float(dihedral_angles(mesh.vertices, mesh.tets).min())
        for method in args.methods:
            for eps in args.epsilons:
                start = time.perf_counter()
                records = [one(mesh, planes, method, eps, args.improve) for planes in chains]
                ok = [r for r in records if not r["error"]]
                row = {"mesh": name, "tets": mesh.tet_count, "worst_in": round(worst_in, 2), "method": method,
                       "epsilon": eps, "cuts": len(records), "refused": len(records) - len(ok),
                       "joined": sum(not r["separated"] for r in ok), "invalid": sum(not r["valid"] for r in records),
                       "volume_gt_1e-9": sum(r["volume_change"] > 1e-9 for r in ok),
                       "max_volume_change": max((r["volume_change"] for r in ok), default=0.0),
                       "worst_dihedral": min((r["min_dihedral"] for r in ok), default=float("nan")),
                       "below_1deg": sum(r["min_dihedral"] < 1.0 for r in ok),
                       "worst_new": min((r["worst_new"] for r in ok), default=float("nan")),
                       "new_below_5deg": sum(r["worst_new"] < TARGET_DEGREES for r in ok),
                       "misses": sum(r["misses"] for r in ok), "misses_input": sum(r["misses_input"] for r in ok),
                       "forced": sum(r["forced"] for r in ok),
                       "min_volume_rel": min((r["min_volume"] for r in ok), default=float("nan")),
                       "seconds": round(time.perf_counter() - start, 1)}
                rows.append(row)
                print("  ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
                      flush=True)
                for r in records:
                    if r["error"]:
                        print("    refused:", r["error"])
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
