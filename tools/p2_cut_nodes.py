#!/usr/bin/env python3
"""Nodes added by cutting quadratic tetrahedra (thesis 6.1.4, table 6.4 and the coarse liver).

    python tools/p2_cut_nodes.py [-o out/p2_cut_nodes] [--quick]

Each mesh is made quadratic and cut once, completely, in its rest configuration by
:class:`wcut.cut.QuadraticCutter` (method ``paulus``), without snapping (epsilon 0, the thesis's
table) and with snapping (epsilon 0.1 and 0.3). It reports the number of cut elements n(v)
and the added nodes per cut element, ``(nodes after - nodes before) / n(v)`` after the
separation, the thesis's ``2 n(k_S) + n(k)``:

- the beams of table 6.4 (``scenes/meshes/beam371.vtu``, ``beam712.vtu``, ``beam4621.vtu``:
  371, 745 and 4663 elements; the thesis has 371, 712 and 4621 and reports about 10.6, 10.2
  and 9.6), cut by the plane of the linear experiment (x = 0.0809 m, figure 5.10), made
  quadratic with straight edges;
- the coarse curved organ (``organ_p2.vtu``, 277 elements), the thesis's coarse-liver worst
  case (about 48 added nodes per cut element), cut by three planes through its body.

Also the relative volume change (by quadrature) and the components after the cut. Writes
``<output>.csv`` and ``<output>.png``; ``--quick`` leaves out beam4621.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from wcut.cut import Plane
from wcut.cut.quadratic import QuadraticCutter
from wcut.quadratic import load_mesh
from wcut.topology import connected_components

MESHES = Path(__file__).resolve().parent.parent / "scenes" / "meshes"
EPSILONS = (0.0, 0.1, 0.3)
#: the plane of the linear experiment (figure 5.10): 0.9 mm from the plane of nodes x = 0.08 m
BEAM_PLANE = Plane([0.0809, 0.0, 0.0], [1.0, 0.0, 0.0])
ORGAN_PLANES = {"organ_x": Plane([0.01, 0.0, 0.0], [1.0, 0.3, 0.2]),
                "organ_y": Plane([0.0, 0.01, 0.005], [0.1, 1.0, 0.3]),
                "organ_z": Plane([0.0, 0.0, 0.012], [0.2, 0.1, 1.0])}
#: thesis table 6.4 and the coarse liver: added nodes per cut element
THESIS = {"beam371": 10.6, "beam712": 10.2, "beam4621": 9.6, "organ": 48.4}


def cut_case(mesh_name: str, plane: Plane, epsilon: float, label: str | None = None) -> dict:
    """Cut ``scenes/meshes/<mesh_name>.vtu`` (made quadratic) by ``plane``; counts and figures."""
    mesh = load_mesh(MESHES / f"{mesh_name}.vtu", order=2)
    result = QuadraticCutter(mesh, "paulus", epsilon).cut(plane)
    after, stats = result.mesh, result.stats
    volume = mesh.volumes().sum()
    return {"case": label or mesh_name, "elements": mesh.tet_count, "epsilon": epsilon,
            "nodes_before": mesh.vertex_count, "nodes_after": after.vertex_count,
            "cut_elements": stats.cut_elements,
            "added_per_cut_element": (after.vertex_count - mesh.vertex_count) / max(stats.cut_elements, 1),
            "snapped": stats.snapped_vertices, "bisections": stats.bisections,
            "volume_change": float((after.volumes().sum() - volume) / volume),
            "components": int(connected_components(after.linear()).max() + 1)}


def run(quick: bool = False) -> list[dict]:
    beams = ("beam371", "beam712") if quick else ("beam371", "beam712", "beam4621")
    rows = []
    for epsilon in EPSILONS:
        rows += [cut_case(name, BEAM_PLANE, epsilon) for name in beams]
        rows += [cut_case("organ_p2", plane, epsilon, label) for label, plane in ORGAN_PLANES.items()]
    return rows


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = list(dict.fromkeys(r["case"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 4.2))
    width = 0.8 / len(EPSILONS)
    for k, epsilon in enumerate(EPSILONS):
        values = [next(r["added_per_cut_element"] for r in rows if r["case"] == c and r["epsilon"] == epsilon)
                  for c in cases]
        ax.bar(np.arange(len(cases)) + (k - 1) * width, values, width, label=f"epsilon {epsilon}")
    for i, case in enumerate(cases):
        thesis = THESIS.get(case, THESIS["organ"] if case.startswith("organ") else None)
        ax.plot([i - 0.45, i + 0.45], [thesis, thesis], "k--", lw=1, label="thesis" if i == 0 else None)
    ax.set_xticks(np.arange(len(cases)), cases)
    ax.set_ylabel("added nodes per cut element")
    ax.set_title("Cutting quadratic tetrahedra (thesis table 6.4; coarse liver: 48)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", default="out/p2_cut_nodes", help="output path without extension")
    parser.add_argument("--quick", action="store_true", help="leave out the 4663-element beam")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = run(args.quick)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(rows, out.with_suffix(".png"))
    for r in rows:
        print(f"{r['case']:10s} eps {r['epsilon']:.1f}: n(v) {r['cut_elements']:4d}, nodes {r['nodes_before']} -> "
              f"{r['nodes_after']}, {r['added_per_cut_element']:5.1f} added per cut element, "
              f"dV/V {r['volume_change']:.1e}, {r['components']} pieces")
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
