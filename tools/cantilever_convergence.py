#!/usr/bin/env python3
"""Static tip deflection of a clamped cantilever under its own weight, against beam theory.

    python tools/cantilever_convergence.py [-o out/cantilever_convergence]

Writes ``.csv`` and ``.png``: the relative error of the tip deflection of a 1 m x 0.1 m x 0.1 m
beam (E = 1 GPa, nu = 0, rho = 1000 kg/m^3, small deflection) meshed with n x n cross-section
cells (10 n along the length, 5 tetrahedra per cell) against Euler-Bernoulli with Timoshenko's
shear correction, and the observed convergence order (thesis 3.5, figure 3.12).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import warp as wp

import wcut
from wcut.model import Model
from wcut.solver import SolverCorotational

L, H, E, RHO, G = 1.0, 0.1, 1.0e9, 1000.0, 9.81


def beam_theory_deflection() -> float:
    """Tip deflection (m): q L^4 / (8 E I) plus the shear term q L^2 / (2 kappa G A)."""
    q, inertia = RHO * G * H * H, H ** 4 / 12
    return q * L ** 4 / (8 * E * inertia) + q * L ** 2 / (2 * (5 / 6) * (E / 2) * H * H)


def tip_deflection(n: int) -> tuple[float, int]:
    """Quasi-static tip deflection (m) with n x n cross-section cells, and the element count."""
    mesh = wcut.beam(10 * n, n, n, size=(L, H, H))
    model = Model(mesh, density=RHO, youngs_modulus=E, poisson_ratio=0.0, gravity=(0, 0, -G),
                  fixed=mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1)))
    solver = SolverCorotational(model, cg_iterations=20000, cg_tolerance=1e-7)
    state, scratch = model.state(), model.state()
    for _ in range(2):  # dt = 1000 s: the mass term vanishes next to dt^2 K, one step is a static solve
        solver.step(state, scratch, None, 1.0e3)
        state, scratch = scratch, state
    tip = mesh.vertices[:, 0] > L - 1e-9
    return float(-(state.particle_q.numpy()[tip, 2] - mesh.vertices[tip, 2]).mean()), model.tet_count


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="out/cantilever_convergence", help="path without extension")
    parser.add_argument("--max-n", type=int, default=6, help="finest cross-section resolution")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING
    exact = beam_theory_deflection()
    rows = []
    for n in range(1, args.max_n + 1):
        deflection, tets = tip_deflection(n)
        rows.append({"n": n, "h_m": H / n, "tets": tets, "tip_deflection_m": deflection,
                     "relative_error": abs(deflection - exact) / exact})
        print(f"n = {n}: {tets} tets, tip {deflection:.6e} m, error {rows[-1]['relative_error']:.4f}")
    h = np.array([r["h_m"] for r in rows])
    err = np.array([r["relative_error"] for r in rows])
    orders = np.log(err[:-1] / err[1:]) / np.log(h[:-1] / h[1:])
    print("observed orders:", " ".join(f"{o:.2f}" for o in orders))

    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    ax.loglog(h, err, "o-", label="corotational P1 (5 tets per cell)")
    ax.loglog(h, err[-1] * (h / h[-1]) ** 2, "k--", lw=0.8, label="order 2")
    ax.loglog(h, err[-1] * (h / h[-1]) ** 1, "k:", lw=0.8, label="order 1")
    ax.set_xlabel("cell size h (m)")
    ax.set_ylabel("relative tip deflection error")
    ax.set_title(f"Cantilever under gravity vs beam theory (tip {exact * 1e3:.3f} mm)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=120)
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
