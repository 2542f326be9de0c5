#!/usr/bin/env python3
"""Crack paths of the fracture variants against the expected path (thesis 6.2, figure 6.16).

Reproduces the precut-sheet experiment of thesis section 6.2 (issue 5): a square sheet of
quadratic triangles with a straight notch from the middle of its left side is pulled until
it breaks (:class:`wcut.fracture.ShellFracture`, maximal principal stress against the tensile
strength, eq 6.3), once per crack-following variant of :data:`wcut.fracture.VARIANTS`:
``none`` (open the existing edge closest to the crack direction; figure 6.16 left),
``spatial`` (snap the edge's far corner to the crack line drawn with the deformed direction;
figure 6.16 middle), ``material`` (snap it to the crack line mapped to the rest configuration,
figure 6.14; figure 6.16 right) and ``split`` (split the triangle ahead of the tip into four
first and snap only nodes the split made; the thesis's future work).

Run::

    .venv/bin/python tools/crack_paths.py [--out out/crack_paths] [--cells 16] [--steps 200]
        [--angle 30] [--strain-rate 1e-3] [--variants none spatial material split]
        [--cases mode-I inclined] [--quiet]

The sheet: 0.1 m x 0.1 m, ``--cells`` x ``--cells`` cells of two triangles (criss-cross
diagonals, :func:`wcut.mesh.precut_sheet`), a notch of 0.3 of the width along y = h/2 (rounded
to whole cells), E = 1 MPa, nu = 0.3, rho = 1000 kg/m^3, 1 mm thick, no gravity, tensile
strength 0.2 MPa, mass damping 5/s, implicit Euler with dt = 1 ms. The load is a growing
affine displacement ``u = eps(t) ((X - c) . n) n`` (c the centre of the sheet, n a unit
direction in the plane, ``eps = strain_rate * (step + 1)``) prescribed on clamped nodes
(held by the solver as fixed nodes, moved by setting their positions every step). The load is
quasi-static: waves cross the sheet in about 3 steps and the damping is strong. At 16 x 16,
strain rates of 2e-4, 4e-4 and 1e-3 per step give the same events and maximal deviations to
0.03 mm (the material variant's mean deviation to 0.25 mm, its minimal quality 0.25 to 0.42);
the crack starts at a strain of about 0.05 (step 49 at the default rate) and cuts through in
10 to 60 steps, one edge per step at most.

- ``mode-I``: n = y; the top and bottom edges are clamped (the sides and the notch are free),
  so the notch opens in mode I and the expected path is the straight line y = h/2 from the
  notch tip, which lies on mesh edges (every variant can follow it exactly);
- ``inclined``: n at ``--angle`` degrees from the y axis, towards +x; every node of the outer
  boundary is clamped (corners and edge nodes on x = 0, x = w, y = 0, y = h; not the notch's
  faces), so the far field is a uniaxial strain along n and the crack runs perpendicular to n:
  the expected path is the straight line through the notch tip along
  ``t = (cos angle, -sin angle)``, which does not follow mesh lines. (At the tip the notch is
  loaded in mixed mode, K_II / K_I = (1 - nu) sin b cos b / (cos^2 b + nu sin^2 b) = 0.37 at
  b = 30 degrees, and the maximal tangential stress criterion kinks the crack by 33 degrees,
  close to the line's 30.)

A run ends after ``--steps`` steps or as soon as the crack from the notch tip reaches the outer
boundary (the edges opened from the tip, :func:`tip_component`, touch it). It fails
when the solver diverges (``SolverCorotational.check`` raises :class:`wcut.SimulationError`),
when the mesh after an event is not a valid sheet of the initial rest area
(:func:`wcut.topology.shell.check_shell`), when anything else raises, or when no crack starts.

How to read the output. The crack path is every opened edge of every event (rest positions,
``CrackEvent.segments``). For each case and variant, ``crack_paths.csv`` (written atomically
into ``--out``) has one row with:

- ``status`` (``ok`` or ``failed``), ``failure`` (why), ``finite``, ``topology_ok``,
  ``crack_started``, ``started_at_tip`` (the first event opened an edge at the notch tip);
- ``first_event_step``, ``steps_run``, ``reached_boundary`` (the crack from the tip cut
  through to the outer boundary);
- ``events``, ``snapped_events``, ``refined_events``, ``other_initiations`` (cracks that
  started anywhere but at the notch tip);
- ``path_length_m`` (total length of the opened edges), ``reach_m`` (how far the path got from
  the tip along the expected direction), ``angle_error_deg`` (angle between the expected
  direction and the chord from the tip to the path point that reached farthest);
- ``mean_deviation_m``, ``max_deviation_m``: distance of the path's corner points from the
  expected line, over the points farther than one cell from the notch tip (on the first cell
  the path is a single edge); the printed table gives them in mm and in cells;
- ``min_quality`` (smallest corner-triangle quality ``4 sqrt(3) A / sum l^2`` of the final
  mesh; 0.87 for the initial right triangles), ``nodes_added``, ``triangles_added``, ``wall_s``.

``crack_paths.png`` has one panel per case: the sheet's outline, the notch (black), the
expected path (dashed) and each variant's path in its own colour (thickest first, so paths that
overlap stay visible). ``none`` can only follow mesh edges (0, 45 or 90 degrees on this grid),
so on the inclined case it deviates by a cell or more; the snapping variants should follow the line more closely, at the price of
a worse mesh (``min_quality``) or, per the thesis, of stability. The exit status is 0 when
every run could be made (a failed run is a result of the experiment, reported in the table and
the CSV), 2 on bad options.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from wcut.fracture import VARIANTS

CSV_NAME = "crack_paths.csv"
PNG_NAME = "crack_paths.png"
CASES = ("mode-I", "inclined")
COLUMNS = ("case", "variant", "cells", "angle_deg", "status", "failure", "finite", "topology_ok", "crack_started",
           "started_at_tip", "first_event_step", "steps_run", "reached_boundary", "events", "snapped_events",
           "refined_events", "other_initiations", "path_length_m", "reach_m", "angle_error_deg",
           "mean_deviation_m", "max_deviation_m", "min_quality", "nodes_added", "triangles_added", "wall_s")

WIDTH = HEIGHT = 0.1          # m
NOTCH_FRACTION = 0.3          # notch length / width
YOUNGS, POISSON, DENSITY, THICKNESS = 1.0e6, 0.3, 1000.0, 1.0e-3   # Pa, 1, kg/m^3, m
STRENGTH = 2.0e5              # Pa, ultimate tensile strength
RAYLEIGH_MASS = 5.0           # 1/s
DT = 1.0e-3                   # s
CG_ITERATIONS = 60
#: Path points at most this many cells from the notch tip are left out of the deviation.
TIP_EXCLUSION_CELLS = 1.0


class Case(NamedTuple):
    """A loading case: the unit load direction ``n`` and which boundary nodes are clamped."""

    name: str
    angle_deg: float       # angle of n from the y axis, towards +x
    n: np.ndarray          # (3,) unit in-plane load direction
    clamp: str             # "top-bottom" or "boundary"

    @property
    def expected_direction(self) -> np.ndarray:
        """The crack direction perpendicular to n in the plane, pointing into the sheet (+x)."""
        t = np.array([self.n[1], -self.n[0], 0.0])
        return t if t[0] >= 0.0 else -t


def make_case(name: str, angle_deg: float) -> Case:
    if name == "mode-I":
        return Case(name, 0.0, np.array([0.0, 1.0, 0.0]), "top-bottom")
    b = math.radians(angle_deg)
    return Case(name, float(angle_deg), np.array([math.sin(b), math.cos(b), 0.0]), "boundary")


def sheet(cells: int):
    """The precut sheet and its notch tip (3,)."""
    from wcut.mesh import precut_sheet

    mesh = precut_sheet(cells, cells, (WIDTH, HEIGHT), notch_length=NOTCH_FRACTION * WIDTH)
    k = int(np.floor(NOTCH_FRACTION * cells + 0.5))  # precut_sheet's rounding to whole cells
    return mesh, np.array([k * WIDTH / cells, HEIGHT / 2, 0.0])


def clamped(X: np.ndarray, case: Case) -> np.ndarray:
    """Boolean mask of the clamped nodes of rest positions ``X`` (the notch faces never)."""
    tol = 1e-9 * WIDTH
    bottom, top = X[:, 1] < tol, X[:, 1] > HEIGHT - tol
    if case.clamp == "top-bottom":
        return bottom | top
    return bottom | top | (X[:, 0] < tol) | (X[:, 0] > WIDTH - tol)


def on_outer_boundary(P: np.ndarray) -> np.ndarray:
    tol = 1e-9 * WIDTH
    return (P[:, 0] < tol) | (P[:, 0] > WIDTH - tol) | (P[:, 1] < tol) | (P[:, 1] > HEIGHT - tol)


class RunFailure(Exception):
    pass


def run(case: Case, variant: str, cells: int, steps: int, strain_rate: float) -> dict:
    """One simulation of ``case`` with the fracture ``variant``: the row of figures plus the
    path segments (``"segments"``, (k, 2, 3) rest positions) and the notch tip."""
    from wcut.errors import SimulationError
    from wcut.fracture import ShellFracture
    from wcut.model import Model
    from wcut.solver import SolverCorotational
    from wcut.topology.shell import check_shell, triangle_qualities

    started = time.perf_counter()
    mesh, tip = sheet(cells)
    center = np.array([WIDTH / 2, HEIGHT / 2, 0.0])
    nodes0, tris0 = mesh.vertex_count, mesh.triangle_count
    area = mesh.area()
    model = Model(mesh, density=DENSITY, youngs_modulus=YOUNGS, poisson_ratio=POISSON, thickness=THICKNESS,
                  gravity=(0.0, 0.0, 0.0), fixed=np.flatnonzero(clamped(mesh.vertices, case)),
                  rayleigh_mass=RAYLEIGH_MASS)
    state, scratch = model.state(), model.state()
    solver = SolverCorotational(model, cg_iterations=CG_ITERATIONS)
    fracture = ShellFracture(mesh, STRENGTH, variant=variant)
    failure, finite, topology_ok, reached, steps_run = "", True, True, False, 0
    n = case.n
    try:
        fixed = model.particle_fixed.numpy() == 1
        for step in range(steps):
            eps = strain_rate * (step + 1)
            q = state.particle_q.numpy()
            X = fracture.mesh.vertices[fixed]
            q[fixed] = X + eps * ((X - center) @ n)[:, None] * n
            state.particle_q.assign(q)
            solver.step(state, scratch, model.control(), DT)
            state, scratch = scratch, state
            steps_run = step + 1
            try:
                solver.check()
            except SimulationError as exc:
                finite = False
                raise RunFailure(f"step {step}: {exc}") from None
            change = fracture.step(model, state)
            if change is None:
                continue
            try:
                check_shell(fracture.mesh, area)
            except Exception as exc:
                topology_ok = False
                raise RunFailure(f"step {step}: check_shell: {exc}") from None
            model, state = model.rebuild(fracture.mesh, change, state)
            scratch = model.state()
            solver = SolverCorotational(model, cg_iterations=CG_ITERATIONS)
            fixed = model.particle_fixed.numpy() == 1
            if on_outer_boundary(tip_component(fracture.events, tip)).any():
                reached = True  # the sheet is cut through from the notch
                break
        if not fracture.events:
            raise RunFailure(f"no crack started in {steps} steps (final strain {strain_rate * steps:.3g})")
    except RunFailure as exc:
        failure = str(exc)
    except Exception as exc:  # anything the solver, the fracture or the rebuild raised
        failure = f"step {steps_run - 1}: {type(exc).__name__}: {exc}"
    events = fracture.events
    segments = np.concatenate([e.segments for e in events]) if events else np.zeros((0, 2, 3))
    final = fracture.mesh

    def at_tip(event) -> bool:
        return bool(np.linalg.norm(event.segments[0, 0] - tip) < 1e-9 * WIDTH)

    row = dict(case=case.name, variant=variant, cells=cells, angle_deg=case.angle_deg,
               status="failed" if failure else "ok", failure=failure, finite=finite, topology_ok=topology_ok,
               crack_started=bool(events),
               started_at_tip=bool(events) and events[0].initiation and at_tip(events[0]),
               first_event_step=events[0].step if events else -1, steps_run=steps_run, reached_boundary=reached,
               events=len(events), snapped_events=sum(e.snapped for e in events),
               refined_events=sum(e.refined for e in events),
               other_initiations=sum(e.initiation and not at_tip(e) for e in events),
               min_quality=float(triangle_qualities(final.vertices, final.triangles).min()),
               nodes_added=final.vertex_count - nodes0, triangles_added=final.triangle_count - tris0,
               segments=segments, tip=tip)
    row.update(path_figures(segments, tip, case.expected_direction, WIDTH / cells))
    row["wall_s"] = time.perf_counter() - started
    return row


def tip_component(events, tip: np.ndarray) -> np.ndarray:
    """(P, 3) rest positions of the crack's corner points connected to the notch ``tip`` by
    opened edges (the tip included)."""
    def key(p):
        return tuple(np.round(np.asarray(p) / WIDTH, 9))

    points, neighbours = {key(tip): tip}, {}
    for event in events:
        for a, b in event.segments:
            points.setdefault(key(a), a)
            points.setdefault(key(b), b)
            neighbours.setdefault(key(a), []).append(key(b))
            neighbours.setdefault(key(b), []).append(key(a))
    seen, todo = {key(tip)}, [key(tip)]
    while todo:
        for q in neighbours.get(todo.pop(), []):
            if q not in seen:
                seen.add(q)
                todo.append(q)
    return np.array([points[k] for k in seen])


def path_figures(segments: np.ndarray, tip: np.ndarray, direction: np.ndarray, cell: float) -> dict:
    """Length, reach, chord angle and deviation from the line through ``tip`` along
    ``direction`` of the path made of ``segments`` (k, 2, 3)."""
    nan = float("nan")
    if not len(segments):
        return dict(path_length_m=0.0, reach_m=0.0, angle_error_deg=nan, mean_deviation_m=nan, max_deviation_m=nan)
    length = float(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).sum())
    points = np.unique(np.round(segments.reshape(-1, 3), 12), axis=0)
    rel = points - tip
    along = rel @ direction
    across = np.linalg.norm(rel - along[:, None] * direction, axis=1)
    far = int(np.argmax(along))
    chord = rel[far]
    angle = math.degrees(math.acos(np.clip(chord @ direction / np.linalg.norm(chord), -1, 1))) \
        if np.linalg.norm(chord) > 0 else nan
    kept = np.linalg.norm(rel, axis=1) > TIP_EXCLUSION_CELLS * cell * (1 + 1e-6)
    return dict(path_length_m=length, reach_m=float(along.max()), angle_error_deg=angle,
                mean_deviation_m=float(across[kept].mean()) if kept.any() else nan,
                max_deviation_m=float(across[kept].max()) if kept.any() else nan)


# --- output ---------------------------------------------------------------------------------

def _format(value):
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def write_csv(rows: list[dict], path: Path) -> None:
    from wcut.io import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            for row in rows:
                writer.writerow({c: _format(row[c]) for c in COLUMNS})


def write_plot(rows: list[dict], cases: list[Case], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    from wcut.io import atomic_path

    colors = dict(zip(VARIANTS, ("C0", "C1", "C2", "C3")))
    fig, axes = plt.subplots(1, len(cases), figsize=(5.6 * len(cases), 5.6), squeeze=False)
    for ax, case in zip(axes[0], cases):
        case_rows = [r for r in rows if r["case"] == case.name]
        ax.plot([0, WIDTH, WIDTH, 0, 0], [0, 0, HEIGHT, HEIGHT, 0], color="0.4", lw=1)
        if case_rows:
            tip = case_rows[0]["tip"]
            ax.plot([0, tip[0]], [tip[1], tip[1]], color="k", lw=2.5, label="notch")
            t = case.expected_direction
            s = _exit_distance(tip, t)
            ax.plot([tip[0], tip[0] + s * t[0]], [tip[1], tip[1] + s * t[1]], "k--", lw=1, label="expected")
        widths = np.linspace(5.0, 1.5, max(len(case_rows), 1))  # overlapping paths stay visible
        for row, lw in zip(case_rows, widths):
            label = (f"{row['variant']}: max dev {row['max_deviation_m'] * 1e3:.2f} mm"
                     if np.isfinite(row["max_deviation_m"]) else f"{row['variant']}")
            if row["status"] != "ok":
                label += " (failed)"
            seg = row["segments"][:, :, :2]
            ax.add_collection(LineCollection(seg, colors=colors.get(row["variant"], "C4"), linewidths=lw,
                                             alpha=0.75, label=label, capstyle="round"))
        ax.set_xlim(-0.03 * WIDTH, 1.03 * WIDTH)
        ax.set_ylim(-0.03 * HEIGHT, 1.03 * HEIGHT)
        ax.set_aspect("equal")
        ax.set(xlabel="x (m)", ylabel="y (m)",
               title=case.name + ("" if case.name == "mode-I" else f": load at {case.angle_deg:g}° from y"))
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _exit_distance(p: np.ndarray, t: np.ndarray) -> float:
    """Distance from ``p`` along ``t`` to the sheet's outline."""
    s = []
    for k, hi in ((0, WIDTH), (1, HEIGHT)):
        if t[k] > 1e-12:
            s.append((hi - p[k]) / t[k])
        elif t[k] < -1e-12:
            s.append(-p[k] / t[k])
    return min(s)


def print_table(rows: list[dict], file=sys.stdout) -> None:
    head = (f"{'case':<9} {'variant':<8} {'status':<6} {'tip':>3} {'events':>6} {'snap':>4} {'refine':>6} "
            f"{'other':>5} {'1st step':>8} {'reach mm':>8} {'mean dev mm':>11} {'max dev mm':>10} "
            f"{'max dev cells':>13} {'angle err':>9} {'min qual':>8} {'+nodes':>6} {'+tris':>5} {'s':>5}")
    print(head, file=file)
    print("-" * len(head), file=file)
    for r in rows:
        cell = WIDTH / r["cells"]
        print(f"{r['case']:<9} {r['variant']:<8} {r['status']:<6} {'yes' if r['started_at_tip'] else 'no':>3} "
              f"{r['events']:>6d} {r['snapped_events']:>4d} {r['refined_events']:>6d} {r['other_initiations']:>5d} "
              f"{r['first_event_step']:>8d} {r['reach_m'] * 1e3:>8.2f} {r['mean_deviation_m'] * 1e3:>11.3f} "
              f"{r['max_deviation_m'] * 1e3:>10.3f} {r['max_deviation_m'] / cell:>13.2f} "
              f"{r['angle_error_deg']:>9.1f} {r['min_quality']:>8.3f} {r['nodes_added']:>6d} "
              f"{r['triangles_added']:>5d} {r['wall_s']:>5.1f}", file=file)
    for r in rows:
        if r["failure"]:
            print(f"FAILED {r['case']}/{r['variant']}: {r['failure']}", file=file)


# --- command line ---------------------------------------------------------------------------

def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/crack_paths", help="output directory (default out/crack_paths)")
    p.add_argument("--cells", type=int, default=16, help="cells along each side (even, >= 4; default 16)")
    p.add_argument("--steps", type=int, default=200, help="most time steps per run (default 200)")
    p.add_argument("--strain-rate", type=float, default=1.0e-3,
                   help="growth of the prescribed strain per step of 1 ms (default 1e-3)")
    p.add_argument("--angle", type=float, default=30.0,
                   help="inclined case: load direction, degrees from the y axis (default 30)")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS),
                   help="fracture variants (default all)")
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES), help="cases (default both)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    args = p.parse_args(argv)
    if args.cells < 4 or args.cells % 2:
        p.error("--cells must be even and at least 4")
    if args.steps < 1:
        p.error("--steps must be at least 1")
    if not (math.isfinite(args.strain_rate) and args.strain_rate > 0):
        p.error("--strain-rate must be positive")
    if not -60.0 <= args.angle <= 60.0:
        p.error("--angle must lie in [-60, 60] degrees (the crack must run into the sheet)")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    started = time.perf_counter()
    cases = [make_case(name, args.angle) for name in args.cases]
    runs = [(c, v) for c in cases for v in args.variants]
    rows = []
    for i, (case, variant) in enumerate(runs, 1):
        row = run(case, variant, args.cells, args.steps, args.strain_rate)
        rows.append(row)
        if not args.quiet:
            dev = row["max_deviation_m"]
            print(f"crack_paths [{i}/{len(runs)}] {case.name}/{variant}: {row['status']}, {row['events']} events, "
                  f"reach {row['reach_m'] * 1e3:.1f} mm, max deviation "
                  f"{'n/a' if not np.isfinite(dev) else f'{dev * 1e3:.2f} mm'}, {row['wall_s']:.1f} s"
                  + (f" ({row['failure']})" if row["failure"] else ""), file=sys.stderr)
    out = Path(args.out)
    write_csv(rows, out / CSV_NAME)
    write_plot(rows, cases, out / PNG_NAME,
               f"precut sheet {WIDTH:g} m x {HEIGHT:g} m, {args.cells}x{args.cells} cells, E = {YOUNGS:g} Pa, "
               f"ν = {POISSON:g}, σ_f = {STRENGTH:g} Pa, strain rate {args.strain_rate:g} per {DT * 1e3:g} ms step, "
               f"≤ {args.steps} steps")
    print(f"{args.cells}x{args.cells} cells (cell {WIDTH / args.cells * 1e3:.2f} mm), strain rate "
          f"{args.strain_rate:g}/step, at most {args.steps} steps; deviation over path points more than "
          f"{TIP_EXCLUSION_CELLS:g} cell from the notch tip")
    print_table(rows)
    print(f"wrote {out / CSV_NAME} and {out / PNG_NAME}; {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
