#!/usr/bin/env python3
"""Nodes and condition number of the system matrix while a beam is cut (thesis figure 5.11).

Reproduces the experiment of thesis section 5.2.2: a deformable beam (by default
``scenes/meshes/beam371.vtu``, 371 tetrahedra and 131 nodes, 0.16 m x 0.04 m x 0.04 m along
x) is cut progressively, step by step, by a plane that lies close to a plane of initial nodes
(figure 5.10), until it is in two pieces. The thesis's remeshing (``paulus``) and Bielser's
subdivision (``bielser``) are compared, each with the snapping thresholds epsilon = 0, 0.1,
0.2, 0.3 (a fraction of the mean rest edge length, thesis 5.1.3).

Run::

    .venv/bin/python tools/cut_conditioning.py [--mesh scenes/meshes/beam371.vtu] [--out-dir out/]
        [--steps 30] [--epsilons 0 0.1 0.2 0.3] [--methods paulus bielser] [--offset 0.05] [--no-improve]
        [--quick]

If ``--mesh`` is not given and the default mesh does not exist, a generated
``beam(8, 2, 2, size=(0.16, 0.04, 0.04))`` is used and a note says so. ``--quick`` (tests) uses
8 steps and epsilon 0 and 0.2 only.

The cut. A straight blade spanning the beam's width (its y range grown by a quarter of the
beam's height on each side: y from -0.01 m to 0.05 m for the default beam) lies in the plane
x = x_c and moves down in z, in ``--steps`` equal steps, from a quarter of the height above the
top to a quarter below the bottom (z from 0.05 m to -0.01 m). x_c is the x coordinate of the
mesh vertex nearest to the middle of the beam's length (x = 0.08 m) plus ``--offset`` (0.05)
times the mean rest edge length: a plane close to the initial nodes, to challenge the methods.
Each step cuts the surface swept so far, limited to the box of this step's sweep
(``cutter.cut(sweep.increment(k), progressive=True)``, exactly as
``wcut.scene`` does for a scene's blade). After every step the mesh is validated with
:func:`wcut.topology.check_topology` (rest volume kept) and its pieces are counted.

The condition number. "The system matrix" is the matrix of the implicit Euler step of the
simulator (thesis eq. 3.69, :mod:`wcut.reference`) without damping, in the rest configuration
(every element rotation the identity)::

    A = M + dt^2 K

with M the lumped mass matrix (rho V / 4 per vertex and element), K the linear-elastic
stiffness of P1 tetrahedra (thesis eq. 3.48) assembled by
:class:`wcut.reference.ScipyCorotationalStep`, rho = 1000 kg/m^3, E = 1e5 Pa, nu = 0.3,
dt = 0.01 s (options). Only the free degrees of freedom are kept: the vertices at the clamped
end x = x_min are fixed. The piece cut off is free, but A stays symmetric positive definite
thanks to M. The condition number is kappa(A) = lambda_max / lambda_min (2-norm), from
``numpy.linalg.eigvalsh`` up to ``DENSE_MAX_DOFS`` (600) free dofs, else from
``scipy.sparse.linalg.eigsh`` (largest with which='LA', smallest by shift-invert about 0,
relative tolerance 1e-10); ``--dense`` forces the dense spectrum.

Writes, atomically, into ``--out-dir``:

- ``cut_conditioning.csv``: one row per (method, epsilon, step), step 0 being the uncut mesh;
  columns ``method, epsilon, step, nodes, elements, cut_elements_total, components,
  condition_number, min_dihedral_deg``. ``cut_elements_total`` is the running sum of the
  cutter's ``stats.cut_elements`` (elements the surface crossed at each step);
- ``cut_conditioning.png``: nodes against the step (left) and the condition number, log
  scale, against the step (right), one line per (method, epsilon).

and prints a summary per (method, epsilon): final nodes, nodes added per cut element, final and
largest condition number. Nodes added per cut element is given twice: over
``cut_elements_total`` (``added/cut``; it counts an element again each time a later step crosses
one of its pieces), and over n(v) (``added/n(v)``), the number of elements of the uncut mesh the
complete cut surface crosses, the quantity of the thesis's analysis (section 5.2.1: about 2
added nodes per cut element after separation for ``paulus``, 4.2 to 5.6 for ``bielser``). The exit
status is 1 when a cut raised or a check failed (the method, epsilon and step are printed),
2 on bad input.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

from wcut.errors import WcutError
from wcut.io import atomic_path
from wcut.mesh import TetMesh, beam, dihedral_angles

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MESH = ROOT / "scenes" / "meshes" / "beam371.vtu"
CSV_NAME = "cut_conditioning.csv"
PNG_NAME = "cut_conditioning.png"
COLUMNS = ("method", "epsilon", "step", "nodes", "elements", "cut_elements_total", "components",
           "condition_number", "min_dihedral_deg")
#: Largest number of free dofs for which the spectrum is computed densely (numpy.linalg.eigvalsh);
#: above it, scipy.sparse.linalg.eigsh (dense costs 0.4 s at 1000 dofs, 23 s at 3700 on 2 cores;
#: both agree to 1e-8 relative on the meshes of this experiment, see the test).
DENSE_MAX_DOFS = 600
#: Blade overhang beyond the beam, as a fraction of the beam's height (z extent).
OVERHANG = 0.25


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="Nodes and condition number while a beam is cut (thesis figure 5.11).")
    p.add_argument("--mesh", default=None,
                   help="tetrahedral mesh of the beam, along x from x = 0 (default scenes/meshes/beam371.vtu; "
                        "a generated 8x2x2 beam if that file is missing)")
    p.add_argument("--out-dir", default="out", help="output directory (default out/)")
    p.add_argument("--steps", type=int, default=None, help="cut steps (default 30, 8 with --quick)")
    p.add_argument("--epsilons", type=float, nargs="+", default=None,
                   help="snapping thresholds (default 0 0.1 0.2 0.3; 0 0.2 with --quick)")
    p.add_argument("--methods", nargs="+", default=["paulus", "bielser"], choices=["paulus", "bielser"],
                   help="cut methods (default paulus bielser)")
    p.add_argument("--offset", type=float, default=0.05,
                   help="distance of the cut plane from the plane of nodes nearest to the beam's middle, "
                        "in mean rest edge lengths (default 0.05)")
    p.add_argument("--youngs-modulus", type=float, default=1.0e5, help="E in Pa (default 1e5)")
    p.add_argument("--poisson-ratio", type=float, default=0.3, help="nu (default 0.3)")
    p.add_argument("--density", type=float, default=1000.0, help="rho in kg/m^3 (default 1000)")
    p.add_argument("--dt", type=float, default=0.01, help="time step in s (default 0.01)")
    p.add_argument("--dense", action="store_true",
                   help=f"always compute the spectrum densely (else only up to {DENSE_MAX_DOFS} free dofs)")
    p.add_argument("--no-improve", dest="improve", action="store_false",
                   help="no local mesh improvement after each cut step (wcut.topology.improve, on by default): "
                        "the thesis's cutter alone")
    p.add_argument("--quick", action="store_true", help="8 steps, epsilon 0 and 0.2 only (for tests)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    if args.steps is None:
        args.steps = 8 if args.quick else 30
    if args.epsilons is None:
        args.epsilons = [0.0, 0.2] if args.quick else [0.0, 0.1, 0.2, 0.3]
    if args.steps < 1:
        p.error("--steps must be at least 1")
    if not all(0.0 <= e < 0.5 for e in args.epsilons):
        p.error("--epsilons must lie in [0, 0.5)")
    if not (args.youngs_modulus > 0 and args.density > 0 and args.dt > 0 and -1.0 < args.poisson_ratio < 0.5):
        p.error("need --youngs-modulus, --density, --dt > 0 and -1 < --poisson-ratio < 0.5")
    return args


def load_mesh(path: str | None) -> TetMesh:
    """The mesh at ``path``; without one, the default mesh or, when it is missing, the
    generated fallback beam (with a printed note)."""
    if path is not None:
        return TetMesh.load(path)
    if DEFAULT_MESH.exists():
        return TetMesh.load(DEFAULT_MESH)
    print(f"note: {DEFAULT_MESH.relative_to(ROOT)} not found; "
          "using beam(8, 2, 2, size=(0.16, 0.04, 0.04), tets_per_hex=5)", file=sys.stderr)
    return beam(8, 2, 2, size=(0.16, 0.04, 0.04), tets_per_hex=5)


def cut_plane_x(mesh: TetMesh, offset: float) -> float:
    """x (m) of the cut plane: the x of the vertex nearest to the middle of the beam's length,
    plus ``offset`` mean rest edge lengths."""
    x = mesh.vertices[:, 0]
    middle = 0.5 * (x.min() + x.max())
    nearest = x[np.argmin(np.abs(x - middle))]
    return float(nearest + offset * mesh.mean_edge_length())


def blade_path(mesh: TetMesh, x_c: float, steps: int) -> np.ndarray:
    """(steps + 1, 2, 3) blade endpoints (m): a segment across the beam's width in the plane
    x = x_c, moving down from above the top to below the bottom."""
    lower, upper = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    margin = OVERHANG * (upper[2] - lower[2])
    z = np.linspace(upper[2] + margin, lower[2] - margin, steps + 1)
    blade = np.empty((steps + 1, 2, 3))
    blade[:, :, 0] = x_c
    blade[:, 0, 1] = lower[1] - margin
    blade[:, 1, 1] = upper[1] + margin
    blade[:, :, 2] = z[:, None]
    return blade


def system_matrix(vertices: np.ndarray, tets: np.ndarray, fixed: np.ndarray, args):
    """A = M + dt^2 K (rest configuration, kg) on the free dofs, CSR."""
    from wcut.reference import ScipyCorotationalStep

    step = ScipyCorotationalStep(vertices, tets, density=args.density, youngs_modulus=args.youngs_modulus,
                                 poisson_ratio=args.poisson_ratio, fixed=fixed)
    A = step.system_matrix(vertices, args.dt)
    free = np.flatnonzero(np.repeat(~fixed, 3))
    return A[free][:, free].tocsr()


def extreme_eigenvalues(A, solver: str = "auto") -> tuple[float, float]:
    """(lambda_min, lambda_max) of the symmetric positive definite matrix A; ``solver`` is
    ``dense``, ``sparse`` or ``auto`` (dense up to ``DENSE_MAX_DOFS`` rows)."""
    if solver == "dense" or (solver == "auto" and A.shape[0] <= DENSE_MAX_DOFS):
        eig = np.linalg.eigvalsh(A.toarray())
        lo, hi = float(eig[0]), float(eig[-1])
    else:
        import scipy.sparse.linalg as spla

        A = A.tocsc()
        hi = float(spla.eigsh(A, k=1, which="LA", tol=1e-10, return_eigenvectors=False)[0])
        lo = float(spla.eigsh(A, k=1, sigma=0.0, which="LM", tol=1e-10, return_eigenvectors=False)[0])
    return lo, hi


def condition_number(vertices: np.ndarray, tets: np.ndarray, fixed: np.ndarray, args) -> float:
    """kappa = lambda_max / lambda_min of A = M + dt^2 K (rest configuration) on the free dofs."""
    solver = "dense" if getattr(args, "dense", False) else "auto"
    lo, hi = extreme_eigenvalues(system_matrix(vertices, tets, fixed, args), solver)
    if not lo > 0.0:
        raise WcutError(f"the system matrix is not positive definite (lambda_min = {lo:.3e})")
    return hi / lo


def measure(topo, x_min: float, tol: float, args) -> dict:
    """Nodes, elements, pieces, condition number and smallest dihedral angle of the live mesh."""
    from wcut.topology import connected_components

    mesh = topo.to_mesh()
    used = np.unique(mesh.tets)
    if len(used) < mesh.vertex_count:  # compact away vertices no element uses
        remap = np.full(mesh.vertex_count, -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        vertices, tets = mesh.vertices[used], remap[mesh.tets]
    else:
        vertices, tets = mesh.vertices, mesh.tets
    fixed = vertices[:, 0] <= x_min + tol
    return {
        "nodes": len(used),
        "elements": len(tets),
        "components": int(connected_components(mesh).max()) + 1,
        "condition_number": condition_number(vertices, tets, fixed, args),
        "min_dihedral_deg": float(dihedral_angles(vertices, tets).min()),
    }


class CaseFailure(Exception):
    def __init__(self, method: str, epsilon: float, step: int, error: Exception):
        super().__init__(f"method={method} epsilon={epsilon:g} step={step}: {type(error).__name__}: {error}")
        self.method, self.epsilon, self.step, self.error = method, epsilon, step, error


def run_case(mesh: TetMesh, method: str, epsilon: float, blade: np.ndarray, args, bar=None) -> list[dict]:
    """Rows (step 0 = uncut mesh) of one progressive cut; raises :class:`CaseFailure`."""
    from wcut.cut import Cutter, SweptBlade
    from wcut.topology import TetTopology, check_topology

    volume0 = float(mesh.volumes().sum())
    x_min = float(mesh.vertices[:, 0].min())
    tol = 1e-9 * float(np.ptp(mesh.vertices[:, 0]))
    try:
        topo = TetTopology(mesh)
        cutter = Cutter(topo, method=method, epsilon=epsilon, improve=args.improve)
        sweep = SweptBlade(blade)
        row = measure(topo, x_min, tol, args)
    except Exception as exc:
        raise CaseFailure(method, epsilon, 0, exc) from exc
    cut_total = 0
    rows = [dict(method=method, epsilon=epsilon, step=0, cut_elements_total=0, **row)]
    if bar is not None:
        bar.update(1)
    for k in range(1, sweep.frame_count):
        increment = sweep.increment(k)
        try:
            if increment is not None:
                result = cutter.cut(increment, progressive=True)
                cut_total += result.stats.cut_elements
            check_topology(topo, volume0)
            row = measure(topo, x_min, tol, args)
        except Exception as exc:  # report where it happened; the caller decides
            raise CaseFailure(method, epsilon, k, exc) from exc
        rows.append(dict(method=method, epsilon=epsilon, step=k, cut_elements_total=cut_total, **row))
        if bar is not None:
            bar.update(1)
    return rows


def crossed_elements(mesh: TetMesh, blade: np.ndarray) -> int:
    """Elements of the uncut mesh that the complete cut surface crosses (the thesis's n(v),
    section 5.2.1), before any snapping: the same for every method and epsilon."""
    from wcut.cut import Cutter, SweptBlade
    from wcut.topology import TetTopology

    topo = TetTopology(mesh)
    surface = SweptBlade(blade).surface_until(len(blade) - 1)
    if surface is None:
        return 0
    return len(Cutter(topo, method="paulus", epsilon=0.0).sample(surface, topo.live_tets()).cut_slots)


def write_csv(rows: list[dict], path: Path) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            for row in rows:
                out = dict(row)
                out["epsilon"] = f"{row['epsilon']:g}"
                out["condition_number"] = f"{row['condition_number']:.6g}"
                out["min_dihedral_deg"] = f"{row['min_dihedral_deg']:.4f}"
                writer.writerow({c: out[c] for c in COLUMNS})


def _cases(rows: list[dict]) -> dict:
    cases: dict = {}
    for row in rows:
        cases.setdefault((row["method"], row["epsilon"]), []).append(row)
    return cases


def write_plot(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    styles = {"paulus": "-", "bielser": "--"}
    markers = {"paulus": "o", "bielser": "s"}
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    epsilons = sorted({row["epsilon"] for row in rows})
    for (method, epsilon), case in _cases(rows).items():
        steps = [r["step"] for r in case]
        style = dict(linestyle=styles.get(method, ":"), marker=markers.get(method, "."), markersize=3,
                     color=colors[epsilons.index(epsilon) % len(colors)], label=f"{method}, ε = {epsilon:g}")
        left.plot(steps, [r["nodes"] for r in case], **style)
        right.plot(steps, [r["condition_number"] for r in case], **style)
    left.set(xlabel="cut step", ylabel="number of nodes", title="Nodes")
    right.set(xlabel="cut step", ylabel="condition number of M + dt² K", title="Condition number", yscale="log")
    for ax in (left, right):
        ax.grid(True, which="both", alpha=0.3)
    right.legend(fontsize=8, loc="upper left")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def summary(rows: list[dict], crossed0: int) -> list[dict]:
    """Per (method, epsilon): final nodes, added nodes per cut element (per element the cutter
    reported, summed over the steps, and per element of the uncut mesh the complete surface
    crosses, ``crossed0``), final and max kappa."""
    out = []
    for (method, epsilon), case in _cases(rows).items():
        first, last = case[0], case[-1]
        cut = last["cut_elements_total"]
        out.append(dict(method=method, epsilon=epsilon, steps=last["step"], nodes0=first["nodes"], nodes=last["nodes"],
                        cut_elements=cut, added_per_cut=(last["nodes"] - first["nodes"]) / cut if cut else float("nan"),
                        added_per_crossed0=(last["nodes"] - first["nodes"]) / crossed0 if crossed0 else float("nan"),
                        components=last["components"], kappa0=first["condition_number"],
                        kappa=last["condition_number"], kappa_max=max(r["condition_number"] for r in case),
                        min_dihedral=min(r["min_dihedral_deg"] for r in case)))
    return out


def print_summary(table: list[dict], file=sys.stdout) -> None:
    head = (f"{'method':<8} {'eps':>4} {'nodes0':>6} {'nodes':>6} {'cut el':>6} {'added/cut':>9} "
            f"{'added/n(v)':>10} {'pieces':>6} {'kappa0':>9} {'kappa final':>11} {'kappa max':>10} {'min dih':>7}")
    print(head, file=file)
    print("-" * len(head), file=file)
    for s in table:
        print(f"{s['method']:<8} {s['epsilon']:>4g} {s['nodes0']:>6d} {s['nodes']:>6d} {s['cut_elements']:>6d} "
              f"{s['added_per_cut']:>9.2f} {s['added_per_crossed0']:>10.2f} {s['components']:>6d} "
              f"{s['kappa0']:>9.3g} {s['kappa']:>11.3g} {s['kappa_max']:>10.3g} {s['min_dihedral']:>7.2f}", file=file)


def _progress(total: int, show: bool):
    if not show:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="cut steps", unit="step", file=sys.stderr, leave=False)


def main(argv=None) -> int:
    args = parse_args(argv)
    started = time.perf_counter()
    try:
        mesh = load_mesh(args.mesh)
    except WcutError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    x_c = cut_plane_x(mesh, args.offset)
    blade = blade_path(mesh, x_c, args.steps)
    out_dir = Path(args.out_dir)
    print(f"mesh {mesh.name}: {mesh.vertex_count} nodes, {mesh.tet_count} elements, "
          f"mean edge {mesh.mean_edge_length():.4g} m; cut plane x = {x_c:.5g} m, {args.steps} steps")
    cases = [(m, e) for m in args.methods for e in args.epsilons]
    bar = _progress(len(cases) * (args.steps + 1), sys.stderr.isatty() and not args.quiet)
    rows: list[dict] = []
    failures: list[CaseFailure] = []
    try:
        for method, epsilon in cases:
            try:
                rows += run_case(mesh, method, epsilon, blade, args, bar)
            except CaseFailure as failure:
                failures.append(failure)
                print(f"FAILED {failure}", file=sys.stderr)
    finally:
        if bar is not None:
            bar.close()
    if rows:
        write_csv(rows, out_dir / CSV_NAME)
        write_plot(rows, out_dir / PNG_NAME,
                   f"{mesh.name}: {mesh.tet_count} elements, {mesh.vertex_count} nodes; cut plane x = {x_c:.4g} m; "
                   f"A = M + dt² K, E = {args.youngs_modulus:g} Pa, ν = {args.poisson_ratio:g}, "
                   f"ρ = {args.density:g} kg/m³, dt = {args.dt:g} s")
        crossed0 = crossed_elements(mesh, blade)
        print(f"n(v) = {crossed0} elements of the uncut mesh cross the complete cut surface; 'cut el' is the "
              "sum over the steps of the elements each cut crossed")
        print_summary(summary(rows, crossed0))
        print(f"wrote {out_dir / CSV_NAME} and {out_dir / PNG_NAME}")
    print(f"{time.perf_counter() - started:.1f} s")
    if failures:
        print(f"{len(failures)} case(s) failed:", file=sys.stderr)
        for failure in failures:
            print(f"  {failure}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
