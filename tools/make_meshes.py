#!/usr/bin/env python3
"""Regenerate the small tetrahedral meshes shipped in ``scenes/meshes/`` (run once, offline).

Needs gmsh's Python API, which is NOT a dependency of wcut (nothing in the package or its
tests imports it); use a throwaway environment:

    python3 -m venv /tmp/meshvenv
    /tmp/meshvenv/bin/pip install gmsh meshio numpy scipy
    /tmp/meshvenv/bin/python tools/make_meshes.py            # writes every mesh
    /tmp/meshvenv/bin/python tools/make_meshes.py --only beam371

(gmsh's wheel may need a few X/GL shared libraries on a bare Linux:
``apt-get install -y libglu1-mesa libxcursor1 libxinerama1 libxft2``.)

It writes, relative to the repository root (``--out DIR`` to change):

- ``scenes/meshes/organ.vtu``: an organ-like (liver-like) body, about 0.16 x 0.10 x 0.07 m,
  centred at the origin, flat-ish bottom facing -z. Its surface is a subdivided icosphere
  mapped onto an ellipsoid and perturbed by a few smooth Gaussian lobes (star-shaped by
  construction); gmsh classifies that triangulation into reparametrizable patches, remeshes
  it at a uniform size and fills it with Delaunay tetrahedra, then optimises (gmsh + Netgen).
- ``scenes/meshes/beam371.vtu``: the beam of thesis figure 5.10 (section 5.2.2, "371
  tetrahedral elements and 131 nodes"): an OCC box 0.16 x 0.04 x 0.04 m, long axis x from
  x = 0, y and z centred on 0. Its edges are split uniformly (9 segments along x, 2 across),
  the faces and the volume are meshed unstructured (MeshAdapt, Delaunay) at a characteristic
  length tuned to give 371 tetrahedra and 130 vertices.
- ``scenes/meshes/beam712.vtu`` and ``beam4621.vtu``: the same box at the two finer
  resolutions of thesis table 6.4 (745 and 4663 tetrahedra; the thesis has 712 and 4621).
- ``scenes/meshes/organ_p2.vtu``: the organ at a coarse size (about 280 elements) as 10-node
  tetrahedra (``tetra10``), the thesis's coarse quadratic liver (6.1.4): boundary edge nodes on
  the smooth organ surface, interior ones relaxed, by wcut's ``to_quadratic`` (so this one
  imports wcut from the repository and needs scipy).

Each file holds only the ``tetra`` (or ``tetra10``) cells (positively oriented, no unused points), written
by meshio as binary, zlib-compressed VTU. The output is deterministic for a given gmsh
version (one thread, fixed ``Mesh.RandomSeed``); the files shipped were made with gmsh
4.15.2. The script prints counts and quality figures (dihedral angles, radius ratio).

``--png PATH`` additionally renders the organ's boundary surface with matplotlib (needs
matplotlib in the environment; ``--render-only`` skips meshing and renders the shipped file).
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = 1

# --------------------------------------------------------------------------- organ surface

#: Semi-axes (m) of the base ellipsoid: 0.16 x 0.10 x 0.07 m.
ORGAN_SEMI_AXES = np.array([0.080, 0.050, 0.035])
#: Smooth lobes: (direction, relative amplitude, angular width in rad). Positive amplitudes
#: bulge out, negative ones dent in; all are low-frequency Gaussians on the sphere.
ORGAN_LOBES = (
    ((-0.55, 0.35, 0.45), 0.26, 0.55),   # big rounded "right lobe" on top
    ((0.75, -0.45, 0.10), -0.20, 0.50),  # notch at the thin end
    ((0.10, 0.80, 0.25), 0.16, 0.45),    # bulge on the +y flank
    ((0.30, -0.20, 0.90), -0.12, 0.50),  # shallow dent on the top face
    ((-0.60, -0.70, -0.20), 0.14, 0.50), # bulge low on the -x/-y side
)
#: Organ mesh size (m): ~4000 tetrahedra.
ORGAN_MESH_SIZE = 0.0095
#: Coarse organ (the quadratic "coarse liver" of thesis 6.1.4): mesh size (m), ~280 tetrahedra.
ORGAN_COARSE_MESH_SIZE = 0.025
#: Beam: box size (m), and per mesh the edge subdivision (along x, across) and characteristic
#: length (m), tuned to the element counts of thesis 5.2.2 and table 6.4: 371 (130 vertices;
#: thesis 371 and 131), 745 (thesis 712) and 4663 (thesis 4621).
BEAM_SIZE = (0.16, 0.04, 0.04)
BEAMS = {"beam371": ((9, 2), 0.022), "beam712": ((11, 2), 0.02), "beam4621": ((24, 6), 0.0068)}


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (N, 3) points and (F, 3) outward (counter-clockwise) triangles."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    points = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
              (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5),
             (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in points]
    for _ in range(level):
        midpoints: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in midpoints:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                midpoints[key] = len(points) - 1
            return midpoints[key]

        refined = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            refined += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = refined
    return np.array(points), np.array(faces, dtype=np.int64)


def organ_radius(u: np.ndarray) -> np.ndarray:
    """Distance (m) from the centre to the organ surface along unit directions ``u`` (N, 3)."""
    r = 1.0 / np.sqrt(((u / ORGAN_SEMI_AXES) ** 2).sum(axis=1))  # the ellipsoid
    scale = np.ones(len(u))
    for direction, amplitude, width in ORGAN_LOBES:
        d = np.asarray(direction, dtype=np.float64)
        angle = np.arccos(np.clip(u @ (d / np.linalg.norm(d)), -1.0, 1.0))
        scale += amplitude * np.exp(-(angle / width) ** 2)
    # flatter bottom: pull in the downward-facing directions smoothly
    down = np.arccos(np.clip(-u[:, 2], -1.0, 1.0))
    scale *= 1.0 - 0.30 * np.exp(-(down / 0.7) ** 2)
    # wedge: thinner towards +x, like the left lobe of a liver
    scale *= 1.0 - 0.25 * np.clip(u[:, 0], 0.0, None) ** 2 * np.abs(u[:, 2])
    return r * scale


def organ_surface(level: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Closed, star-shaped, outward-oriented triangulation of the organ, centred on its
    volume centroid: (N, 3) points (m) and (F, 3) triangles."""
    u, faces = icosphere(level)
    points = u * organ_radius(u)[:, None]
    a, b, c = (points[faces[:, k]] for k in range(3))
    six_v = np.einsum("ij,ij->i", a, np.cross(b, c))  # 6 x signed volume of (0, a, b, c)
    centroid = (six_v[:, None] * (a + b + c)).sum(axis=0) / (4.0 * six_v.sum())
    return points - centroid, faces


# --------------------------------------------------------------------------- gmsh helpers


def _gmsh_start(name: str):
    import gmsh

    gmsh.initialize(["make_meshes"], readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.model.add(name)
    return gmsh


def _gmsh_mesh_volume(gmsh, size: float, algorithm_2d: int, algorithm_3d: int) -> tuple[np.ndarray, np.ndarray]:
    """Mesh the current model in 3D at a uniform size; return compact (points, tets)."""
    gmsh.option.setNumber("Mesh.MeshSizeMin", size)
    gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", algorithm_2d)
    gmsh.option.setNumber("Mesh.Algorithm3D", algorithm_3d)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.option.setNumber("Mesh.OptimizeNetgen", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", SEED)
    gmsh.model.mesh.generate(3)
    tags, coords, _ = gmsh.model.mesh.getNodes()
    _, connectivity = gmsh.model.mesh.getElementsByType(4)  # 4-node tetrahedra
    lookup = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    lookup[tags.astype(np.int64)] = np.arange(len(tags))
    tets = lookup[connectivity.astype(np.int64)].reshape(-1, 4)
    return compact(coords.reshape(-1, 3), tets)


def compact(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop points no tetrahedron uses and orient every tetrahedron positively."""
    used = np.unique(tets)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    points, tets = np.ascontiguousarray(points[used], dtype=np.float64), remap[tets]
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return points, tets


def mesh_organ_p2() -> tuple[np.ndarray, np.ndarray]:
    """The coarse organ as 10-node elements: boundary edge nodes on the smooth organ surface,
    interior ones relaxed (wcut's ``to_quadratic``, thesis 6.1.1)."""
    sys.path.insert(0, ROOT)
    from wcut.mesh import TetMesh
    from wcut.quadratic import to_quadratic

    points, tets = mesh_organ(ORGAN_COARSE_MESH_SIZE)
    quadratic = to_quadratic(TetMesh(points, tets, name="organ_p2"), organ_surface())
    return quadratic.vertices, quadratic.tets


def mesh_organ(size: float = ORGAN_MESH_SIZE) -> tuple[np.ndarray, np.ndarray]:
    gmsh = _gmsh_start("organ")
    points, faces = organ_surface()
    surface = gmsh.model.addDiscreteEntity(2)
    gmsh.model.mesh.addNodes(2, surface, list(range(1, len(points) + 1)), points.ravel().tolist())
    gmsh.model.mesh.addElementsByType(surface, 2, [], (faces + 1).ravel().tolist())
    # one smooth surface: no sharp features; split into patches gmsh can reparametrize
    gmsh.model.mesh.classifySurfaces(40.0 * math.pi / 180.0, True, True, math.pi)
    gmsh.model.mesh.createGeometry()
    loop = gmsh.model.geo.addSurfaceLoop([tag for _, tag in gmsh.model.getEntities(2)])
    gmsh.model.geo.addVolume([loop])
    gmsh.model.geo.synchronize()
    try:
        return _gmsh_mesh_volume(gmsh, size, algorithm_2d=6, algorithm_3d=1)
    finally:
        gmsh.finalize()


def mesh_beam(segments: tuple[int, int] = BEAMS["beam371"][0], size: float = BEAMS["beam371"][1]
              ) -> tuple[np.ndarray, np.ndarray]:
    gmsh = _gmsh_start("beam")
    lx, ly, lz = BEAM_SIZE
    gmsh.model.occ.addBox(0.0, -ly / 2, -lz / 2, lx, ly, lz)
    gmsh.model.occ.synchronize()
    # fix only the edge subdivision (segments along x, across); faces and volume are meshed
    # unstructured (MeshAdapt surfaces, Delaunay volume)
    for _, curve in gmsh.model.getEntities(1):
        start, end = gmsh.model.getBoundary([(1, curve)])
        pa, pb = gmsh.model.getValue(0, abs(start[1]), []), gmsh.model.getValue(0, abs(end[1]), [])
        along_x = abs(pa[0] - pb[0]) > 1e-9
        gmsh.model.mesh.setTransfiniteCurve(curve, segments[0 if along_x else 1] + 1)
    try:
        return _gmsh_mesh_volume(gmsh, size, algorithm_2d=1, algorithm_3d=1)
    finally:
        gmsh.finalize()


# --------------------------------------------------------------------------- quality

_EDGES = ((0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 0, 2), (2, 3, 0, 1))


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = points[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def dihedral_angles(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(M, 6) interior dihedral angles (degrees) at the six edges of each tetrahedron."""
    p = points[tets]
    out = []
    for a, b, c, d in _EDGES:
        e = p[:, b] - p[:, a]
        n1 = np.cross(e, p[:, c] - p[:, a])
        n2 = np.cross(e, p[:, d] - p[:, a])
        cos = np.einsum("ij,ij->i", n1, n2) / (np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=1)


def radius_ratios(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """3 r_in / R_circ per tetrahedron (1 for the regular tetrahedron, 0 for a flat one)."""
    p = points[tets]
    a, b, c, d = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
    u, v, w = b - a, c - a, d - a
    six_v = np.einsum("ij,ij->i", u, np.cross(v, w))
    area = sum(np.linalg.norm(np.cross(q - o, r - o), axis=1) / 2 for o, q, r in ((b, c, d), (a, c, d), (a, b, d), (a, b, c)))
    r_in = np.abs(six_v) / 2.0 / area
    num = (np.cross(v, w) * (u * u).sum(1)[:, None] + np.cross(w, u) * (v * v).sum(1)[:, None]
           + np.cross(u, v) * (w * w).sum(1)[:, None])
    r_circ = np.linalg.norm(num, axis=1) / np.abs(2.0 * six_v)
    return 3.0 * r_in / r_circ


def quality(points: np.ndarray, tets: np.ndarray) -> dict:
    tets = tets[:, :4]  # the corners of quadratic elements
    dih = dihedral_angles(points, tets)
    rr = radius_ratios(points, tets)
    return {
        "vertices": len(points), "tetrahedra": len(tets),
        "volume_m3": float(signed_volumes(points, tets).sum()),
        "extent_m": (points.max(axis=0) - points.min(axis=0)).round(4).tolist(),
        "min_dihedral_deg": float(dih.min()), "mean_dihedral_deg": float(dih.mean()),
        "max_dihedral_deg": float(dih.max()),
        "min_radius_ratio": float(rr.min()), "mean_radius_ratio": float(rr.mean()),
    }


# --------------------------------------------------------------------------- output


def write_vtu(path: str, points: np.ndarray, tets: np.ndarray) -> None:
    """Binary, zlib-compressed VTU with only the tetra (or tetra10) cells; written atomically."""
    import meshio

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp.vtu"
    cell = "tetra10" if tets.shape[1] == 10 else "tetra"
    meshio.write(tmp, meshio.Mesh(points, [(cell, tets.astype(np.int64))]), binary=True, compression="zlib")
    os.replace(tmp, path)


def boundary_triangles(tets: np.ndarray) -> np.ndarray:
    """Outward boundary triangles of positively oriented tetrahedra."""
    faces = tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3)
    _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def render_organ(vtu: str, png: str) -> None:
    """Shaded views of the organ's boundary surface (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import meshio
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    data = meshio.read(vtu)
    points = data.points
    tets = np.concatenate([b.data for b in data.cells if b.type == "tetra"])
    tri = points[boundary_triangles(tets)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.35 + 0.65 * np.clip(normal @ light, 0.0, 1.0)
    colours = np.array([0.74, 0.32, 0.26])[None, :] * shade[:, None]
    fig = plt.figure(figsize=(12, 4.2))
    views = (("perspective", 25, -60), ("top (+z)", 90, -90), ("front (-y)", 0, -90))
    for k, (title, elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, 3, k + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors=(0, 0, 0, 0.12), linewidths=0.2))
        h = 0.09
        ax.set_xlim(-h, h), ax.set_ylim(-h, h), ax.set_zlim(-h, h)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev, azim)
        ax.set_title(title)
        ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.set_zlabel("z (m)")
        ax.tick_params(labelsize=6)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(4))
    fig.suptitle(f"scenes/meshes/organ.vtu: {len(points)} vertices, {len(tets)} tetrahedra")
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=os.path.join(ROOT, "scenes", "meshes"), help="output folder")
    parser.add_argument("--only", choices=("organ", "organ_p2", *BEAMS), help="write one mesh only")
    parser.add_argument("--png", help="also render the organ's surface to this PNG (needs matplotlib)")
    parser.add_argument("--render-only", action="store_true", help="with --png: render the existing organ.vtu")
    args = parser.parse_args(argv)
    if not args.render_only:
        import gmsh

        print(f"gmsh {gmsh.__version__}")
        makers = {"organ": mesh_organ, "organ_p2": mesh_organ_p2,
                  **{name: (lambda spec=spec: mesh_beam(*spec)) for name, spec in BEAMS.items()}}
        for name, make in makers.items():
            if args.only and name != args.only:
                continue
            points, tets = make()
            path = os.path.join(args.out, f"{name}.vtu")
            write_vtu(path, points, tets)
            q = quality(points, tets)
            print(f"{path}: {os.path.getsize(path)} bytes")
            for key, value in q.items():
                print(f"  {key}: {value:.4g}" if isinstance(value, float) else f"  {key}: {value}")
    if args.png:
        render_organ(os.path.join(args.out, "organ.vtu"), args.png)
        print(f"{args.png} written")
    return 0


if __name__ == "__main__":
    sys.exit(main())
