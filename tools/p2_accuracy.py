#!/usr/bin/env python3
"""Accuracy of linear (P1) against quadratic (P2) tetrahedra on a static cantilever
(thesis 3.5, figure 3.12 and volumetric locking).

    python tools/p2_accuracy.py [-o out/p2_accuracy] [--reference-n 6]

A 1 m x 0.2 m x 0.2 m beam (E = 10 MPa, rho = 1000 kg/m^3) clamped at x = 0 sags under its own
weight; it is meshed with 5n x n x n cells of 5 tetrahedra. Each mesh is solved statically
(linear elasticity, the corotational operator at rest, assembled by ``wcut.reference`` and
``wcut.reference_p2`` and solved directly). Against a converged reference (P2 at
``--reference-n``), it reports:

- the relative energy-norm error ``sqrt((C_ref - C_h) / C_ref)`` from the compliance
  ``C = f . u`` (with consistent loads, ``C - C_h`` is the squared energy-norm error), whose
  order is 1 for P1 and 2 for P2, and the relative tip-deflection error, at Poisson ratio 0;
- volumetric locking: the tip-deflection error of P1 and P2 at comparable numbers of
  degrees of freedom for Poisson ratios 0.3 to 0.499.

Writes ``<output>.csv`` (one row per solve) and ``<output>.png`` (the two studies).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

import wcut
from wcut import reference_p2
from wcut.quadratic import to_quadratic
from wcut.reference import ScipyCorotationalStep

LENGTH, SIDE, YOUNGS, DENSITY, GRAVITY = 1.0, 0.2, 1.0e7, 1000.0, 9.81


def cantilever(order: int, n: int, poisson_ratio: float) -> dict:
    """Static sag of the cantilever with 5n x n x n cells of order ``order`` elements:
    degrees of freedom, compliance ``f . u`` (J) and mean tip deflection (m, negative down)."""
    mesh = wcut.beam(5 * n, n, n, size=(LENGTH, SIDE, SIDE))
    gravity = (0.0, 0.0, -GRAVITY)
    if order == 2:
        quadratic = to_quadratic(mesh)
        points, tets = quadratic.vertices, quadratic.tets
        K = reference_p2.stiffness_matrix(points, tets, YOUNGS, poisson_ratio)
        load = reference_p2.body_load(points, tets, DENSITY, gravity)
    else:
        points = mesh.vertices
        step = ScipyCorotationalStep(points, mesh.tets, density=DENSITY, youngs_modulus=YOUNGS,
                                     poisson_ratio=poisson_ratio, gravity=gravity)
        K, load = step.stiffness_matrix(points), step.masses[:, None] * np.asarray(gravity)
    u = reference_p2.static_solve(K, load, np.flatnonzero(points[:, 0] < 1e-9))
    tip = points[:, 0] > LENGTH - 1e-9
    return {"order": order, "n": n, "poisson_ratio": poisson_ratio, "dofs": 3 * len(points),
            "compliance_J": float((load * u).sum()), "tip_deflection_m": float(u[tip, 2].mean())}


def observed_order(values, h) -> np.ndarray:
    """Orders ``log(e_k / e_k+1) / log(h_k / h_k+1)`` between successive refinements."""
    e, h = np.asarray(values, float), np.asarray(h, float)
    return np.log(e[:-1] / e[1:]) / np.log(h[:-1] / h[1:])


def convergence(levels_p1, levels_p2, reference_n: int, poisson_ratio: float = 0.0) -> list[dict]:
    """Energy-norm and tip errors of P1 and P2 on the given levels against P2 at ``reference_n``."""
    reference = cantilever(2, reference_n, poisson_ratio)
    rows = []
    for order, levels in ((1, levels_p1), (2, levels_p2)):
        for n in levels:
            row = cantilever(order, n, poisson_ratio)
            row["energy_error"] = float(np.sqrt(abs(reference["compliance_J"] - row["compliance_J"])
                                                / reference["compliance_J"]))
            row["tip_error"] = abs(row["tip_deflection_m"] / reference["tip_deflection_m"] - 1.0)
            row["study"] = "convergence"
            rows.append(row)
    return rows


def locking(poisson_ratios, n_p1: int, n_p2: int, reference_n: int) -> list[dict]:
    """Tip errors of P1 (n_p1) and P2 (n_p2) against P2 at ``reference_n``, per Poisson ratio."""
    rows = []
    for nu in poisson_ratios:
        reference = cantilever(2, reference_n, nu)
        for order, n in ((1, n_p1), (2, n_p2)):
            row = cantilever(order, n, nu)
            row["tip_error"] = abs(row["tip_deflection_m"] / reference["tip_deflection_m"] - 1.0)
            row["study"] = "locking"
            rows.append(row)
    return rows


def _plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.3))
    for order, marker, color in ((1, "o", "C0"), (2, "s", "C1")):
        conv = [r for r in rows if r["study"] == "convergence" and r["order"] == order]
        h = np.array([SIDE / r["n"] for r in conv])
        err = np.array([r["energy_error"] for r in conv])
        p = observed_order(err, h)[-1]
        ax1.loglog(h, err, marker + "-", color=color, label=f"P{order} energy norm (last order {p:.2f})")
        ax1.loglog(h, [r["tip_error"] for r in conv], marker + ":", color=color, label=f"P{order} tip deflection")
        ax1.loglog(h, err[-1] * (h / h[-1]) ** order, "k--", lw=0.7)
    ax1.set_xlabel("cell size h (m)")
    ax1.set_ylabel("relative error")
    ax1.set_title("Cantilever, Poisson ratio 0 (dashed: order 1 and 2)")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=8)
    for order, marker in ((1, "o"), (2, "s")):
        lock = [r for r in rows if r["study"] == "locking" and r["order"] == order]
        ax2.semilogy([r["poisson_ratio"] for r in lock], [r["tip_error"] for r in lock], marker + "-",
                     label=f"P{order}, {lock[0]['dofs']} dofs")
    ax2.set_xlabel("Poisson ratio")
    ax2.set_ylabel("relative tip deflection error")
    ax2.set_title("Volumetric locking")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="out/p2_accuracy", help="path without extension")
    parser.add_argument("--reference-n", type=int, default=6, help="P2 resolution of the reference")
    args = parser.parse_args(argv)
    ref = args.reference_n
    rows = convergence([1, 2, 3, 4, 6][: max(2, ref - 1)], list(range(1, max(3, ref - 1))), ref)
    k = max(1, (ref - 1) // 2)  # P2 at n = k has about the degrees of freedom of P1 at n = 2k
    rows += locking((0.3, 0.45, 0.48, 0.49, 0.499), n_p1=2 * k, n_p2=k, reference_n=ref)
    for row in rows:
        print(", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    for order in (1, 2):
        conv = [r for r in rows if r["study"] == "convergence" and r["order"] == order]
        orders = observed_order([r["energy_error"] for r in conv], [1.0 / r["n"] for r in conv])
        print(f"P{order} energy-norm orders: " + " ".join(f"{o:.2f}" for o in orders))
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    fields = ["study", "order", "n", "poisson_ratio", "dofs", "compliance_J", "tip_deflection_m", "energy_error",
              "tip_error"]
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows(rows)
    _plot(rows, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
