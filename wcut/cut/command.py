"""``wcut cut``: cut a rest-configuration mesh file and report what changed (DESIGN.md)."""

from __future__ import annotations

import json

import numpy as np

from ..io import atomic_path, check_writable
from ..mesh import check_mesh_format, dihedral_angles
from ..quadratic import load_mesh
from ..topology import TetTopology
from .cutter import CutError, Cutter
from .quadratic import QuadraticCutter
from .separation import pieces, plane_separation
from .surface import CutSurface, Plane, TriangleSurface


def parse_plane(text: str) -> Plane:
    """A plane from ``px,py,pz,nx,ny,nz`` (a point and a normal, metres)."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 6 or not np.isfinite(values).all():
        raise CutError(f"--plane: expected six numbers px,py,pz,nx,ny,nz, got {text!r}")
    return Plane(values[:3], values[3:])


def cut_mesh(mesh, surface: CutSurface, method: str = "paulus", epsilon: float = 0.1):
    """Cut ``mesh`` (rest configuration; a :class:`~wcut.mesh.TetMesh` or a
    :class:`~wcut.quadratic.QuadraticTetMesh`) with ``surface``; returns (mesh after, report
    dict). Volumes are exact for curved elements, the angles and pieces are the corners'.
    ``components`` counts pieces as a simulation sees them: elements sharing a vertex move
    together (:func:`wcut.cut.separation.pieces`).

    Raises CutError when the surface misses the mesh, or when a plane cut (complete) left a
    piece on both sides of the plane (:func:`wcut.cut.separation.plane_separation`)."""
    if getattr(mesh, "order", 1) == 2:
        cutter = QuadraticCutter(mesh, method=method, epsilon=epsilon)
        result = cutter.cut(surface)
        after, stats, corner_cutter = result.mesh, result.stats, cutter.cutter
    else:
        topology = TetTopology(mesh)
        corner_cutter = Cutter(topology, method=method, epsilon=epsilon)
        result = corner_cutter.cut(surface)
        after, stats = topology.to_mesh(name=mesh.name), result.stats
    if result.change.is_empty:
        raise CutError(f"the cut surface misses the mesh {mesh.name} (no element crossed)")
    before_corners = mesh.linear()
    corners = after.linear()
    if isinstance(surface, Plane):
        separation = plane_separation(corners.vertices, corners.tets, surface, corner_cutter.tolerance,
                                      mean_edge_length=corner_cutter.mean_edge_length,
                                      in_plane=corner_cutter.in_plane)
        if not separation.separated:
            raise CutError(f"the cut did not separate {mesh.name}: {separation.describe()}; nothing written")
    angles = dihedral_angles(corners.vertices, corners.tets).reshape(len(corners.tets), -1).min(axis=1)
    volumes = after.volumes()
    report = {
        "nodes_before": mesh.vertex_count,
        "nodes_after": after.vertex_count,
        "elements_before": mesh.tet_count,
        "elements_after": after.tet_count,
        "cut_elements": stats.cut_elements,
        "volume_before": float(mesh.volumes().sum()),
        "volume_after": float(volumes.sum()),
        "min_dihedral_deg": float(angles.min()),
        "min_dihedral_deg_before": float(dihedral_angles(before_corners.vertices, before_corners.tets).min()),
        "elements_below_1deg": int((angles < 1.0).sum()),
        "elements_below_5deg": int((angles < 5.0).sum()),
        "min_volume_to_median": float(volumes.min() / np.median(volumes)),
        "components": int(pieces(corners.tets, corners.vertex_count).max() + 1),
        "method": method,
        "epsilon": epsilon,
        "order": getattr(mesh, "order", 1),
    }
    return after, report


def run_cut(mesh_in, mesh_out, *, plane: str | None = None, surface: str | None = None, method: str = "paulus",
            epsilon: float = 0.1, order: int = 1, report_path=None) -> dict:
    """The ``wcut cut`` command: read, cut, write the mesh and the JSON report atomically.
    With ``order`` 2 the elements are quadratic: a ``tetra10`` input is cut as it is, linear
    input is made quadratic first (straight edges), and the output holds ``tetra10`` cells."""
    if (plane is None) == (surface is None):
        raise CutError("give exactly one cut surface: --plane px,py,pz,nx,ny,nz or --surface TRIS.obj")
    if order not in (1, 2):
        raise CutError(f"--order {order}: expected 1 (linear) or 2 (quadratic)")
    check_mesh_format(mesh_out)
    check_writable(mesh_out)
    if report_path is not None:
        check_writable(report_path)
    cut_surface = parse_plane(plane) if plane is not None else TriangleSurface.load(surface)
    mesh = load_mesh(mesh_in, order)
    after, report = cut_mesh(mesh, cut_surface, method=method, epsilon=epsilon)
    if report_path is None:
        after.save(mesh_out)
        return report
    with atomic_path(report_path) as tmp:  # renamed after the mesh is written: both or neither
        with open(tmp, "w") as f:
            json.dump(report, f, indent=2)
        after.save(mesh_out)
    return report
