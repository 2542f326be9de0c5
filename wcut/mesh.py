"""Tetrahedral meshes: validation, I/O through meshio, generators and boundary extraction.

A :class:`TetMesh` is the host-side (numpy, float64) description of a volumetric object:
rest vertex positions in metres and tetrahedra as four vertex indices, every one positively
oriented (``det[v1-v0, v2-v0, v3-v0] > 0``). It is what the topology manager edits and what
:class:`wcut.model.Model` is built from. Construction validates the input (thesis 3.2: the
elements must form a conforming discretization), so every later stage can rely on:

- finite coordinates, indices in range, every vertex referenced by some tetrahedron;
- no degenerate element (volume above a relative tolerance);
- positive orientation (negatively oriented input elements are reoriented);
- manifold faces: a triangle is shared by at most two tetrahedra.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from dataclasses import dataclass

import numpy as np

from . import shell
from .errors import MeshError, MeshNotice

#: Faces of a positively oriented tetrahedron (v0, v1, v2, v3), each ordered so its normal
#: (right-hand rule) points out of the tetrahedron. Face k is opposite vertex k.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)

#: Relative volume below which an element counts as degenerate: |V| < DEGENERATE_TOL * l^3,
#: with l the element's longest edge (a regular tetrahedron has 0.118). The simulation runs in
#: float32: flatter elements are not even stress-free at rest once their corners are rounded.
DEGENERATE_TOL = 1e-6


def tet_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes (m^3) of tetrahedra: det[v1-v0, v2-v0, v3-v0] / 6."""
    v0 = vertices[tets[:, 0]]
    d1 = vertices[tets[:, 1]] - v0
    d2 = vertices[tets[:, 2]] - v0
    d3 = vertices[tets[:, 3]] - v0
    return np.einsum("ij,ij->i", np.cross(d1, d2), d3) / 6.0


def edge_matrices(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Edge matrices ``[x0 - x3 | x1 - x3 | x2 - x3]`` (M, 3, 3) of tetrahedra, in metres.

    Of rest positions this is ``Dm``: ``Dm^{-1}`` maps positions to the barycentric coordinates
    of nodes 0..2 (thesis eq. 3.16), so its rows are the shape-function gradients. Of current
    positions it is ``Ds``, and ``F = Ds Dm^{-1}`` (eq. 3.20).
    """
    X = vertices[tets]
    return np.stack([X[:, 0] - X[:, 3], X[:, 1] - X[:, 3], X[:, 2] - X[:, 3]], axis=2)


def unique_rows(rows: np.ndarray, base: int, **options):
    """``np.unique(rows, axis=0, **options)`` for rows (K, k) of integers in [0, base): the
    same arrays, a tenth of the time (each row is sorted as one number, ``sum rows[:, i] *
    base**(k-1-i)``, where that fits in an int64)."""
    rows = np.asarray(rows, dtype=np.int64)
    k = rows.shape[1]
    base = max(int(base), 1)
    if base ** k >= 2**63:
        return np.unique(rows, axis=0, **options)
    codes = rows[:, 0].copy()
    for i in range(1, k):
        codes *= base
        codes += rows[:, i]
    result = np.unique(codes, **options)
    codes = result[0] if isinstance(result, tuple) else result
    unique = np.empty((len(codes), k), dtype=np.int64)
    for i in range(k - 1, -1, -1):
        codes, unique[:, i] = np.divmod(codes, base)
    return (unique, *result[1:]) if isinstance(result, tuple) else unique


def _longest_edges(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    lengths = [np.linalg.norm(vertices[tets[:, a]] - vertices[tets[:, b]], axis=1) for a, b in pairs]
    return np.max(lengths, axis=0)


def _face_keys(faces: np.ndarray) -> np.ndarray:
    """Orientation-independent keys of triangles (sorted vertex triples), shape (F, 3)."""
    return np.sort(faces, axis=1)


@dataclass(frozen=True)
class BoundarySurface:
    """The boundary of a tetrahedral mesh as a triangle surface.

    Attributes:
        triangles: (F, 3) vertex indices into the volume mesh, counter-clockwise seen from
            outside (outward normals).
        vertex_ids: (B,) sorted indices of the volume vertices that lie on the boundary.
        local_triangles: (F, 3) the same triangles indexed into ``vertex_ids``.
    """

    triangles: np.ndarray
    vertex_ids: np.ndarray
    local_triangles: np.ndarray


class _VertexQueries:
    """Queries shared by linear and quadratic meshes (``vertices`` (N, 3), ``tets`` (M, k),
    ``source_vertex_ids``)."""

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def tet_count(self) -> int:
        return len(self.tets)

    def vertex_from_source(self, index: int) -> int:
        """This mesh's index of vertex ``index`` of the loaded file (see ``source_vertex_ids``);
        -1 if the file's vertex is not part of the mesh or out of range."""
        if self.source_vertex_ids is None:
            return index if 0 <= index < self.vertex_count else -1
        position = int(np.searchsorted(self.source_vertex_ids, index))
        found = position < len(self.source_vertex_ids) and self.source_vertex_ids[position] == index
        return position if found else -1

    def vertices_in_box(self, lower, upper) -> np.ndarray:
        """Indices of vertices inside the closed axis-aligned box [lower, upper] (metres)."""
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        inside = np.all((self.vertices >= lower) & (self.vertices <= upper), axis=1)
        return np.flatnonzero(inside)


def read_meshio(path: str | os.PathLike):
    """A mesh file as a ``meshio.Mesh``: gmsh's first format by :mod:`wcut.gmsh_v1`, any other
    by meshio with its messages silenced. MeshError when missing or unreadable, with meshio's
    own reason."""
    import meshio

    from . import gmsh_v1

    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(f"{path}: no such file")
    if os.path.isfile(path) and gmsh_v1.is_gmsh_v1(path):
        return gmsh_v1.read(path)
    said = io.StringIO()
    try:
        # meshio prints its own messages and may call sys.exit() on a malformed file
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            return meshio.read(path)
    except (Exception, SystemExit) as exc:  # ReadError, KeyError, ValueError, SystemExit, ...
        detail = str(exc) if not isinstance(exc, SystemExit) else ""
        if not detail or detail.isdigit():
            lines = [line.strip() for line in said.getvalue().splitlines() if line.strip()]
            detail = lines[-1] if lines else f"malformed file ({type(exc).__name__})"
        raise MeshError(f"{path}: cannot read mesh: {detail}") from None


def notice_unused_vertices(name: str, data) -> None:
    """Say in one line (a :class:`~wcut.errors.MeshNotice`) that the vertices of ``data`` (a
    ``meshio.Mesh``) that no cell uses are dropped, if there are any."""
    in_any_cell = np.zeros(len(data.points), dtype=bool)
    for block in data.cells:
        ids = np.asarray(block.data, dtype=np.int64).ravel()
        in_any_cell[ids[(ids >= 0) & (ids < len(in_any_cell))]] = True
    unused = np.flatnonzero(~in_any_cell)
    if not len(unused):
        return
    first = ", ".join(str(int(i)) for i in unused[:5]) + (", ..." if len(unused) > 5 else "")
    warnings.warn(f"{name}: {len(unused)} vertices no cell uses are dropped (file indices {first})",
                  MeshNotice, stacklevel=3)


#: Extensions of the meshio formats that hold tetrahedra (linear and quadratic). Others
#: (.stl, .obj, .ply: surfaces; .xyz: points) would drop them or fail after the work is done.
VOLUME_MESH_FORMATS = (".vtu", ".vtk", ".msh", ".mesh", ".meshb", ".xdmf", ".xmf", ".med", ".inp")


def check_mesh_format(path: str | os.PathLike) -> None:
    """Raise MeshError unless ``path``'s extension names a format that holds tetrahedra."""
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix not in VOLUME_MESH_FORMATS:
        raise MeshError(f"{os.fspath(path)}: cannot write a tetrahedral mesh as {suffix or 'a file without an extension'} "
                        f"(use one of {', '.join(VOLUME_MESH_FORMATS)})")


class TetMesh(_VertexQueries):
    """A validated tetrahedral mesh in its rest configuration.

    Args:
        vertices: (N, 3) rest positions in metres.
        tets: (M, 4) vertex indices of the tetrahedra. Negatively oriented elements are
            reoriented (two vertices swapped); ``reoriented_count`` says how many.
        name: used in error messages (a file name, a generator call).

    Raises:
        MeshError: NaN or infinite coordinates, bad shapes or indices, unreferenced vertices,
            a degenerate element, or a face shared by more than two elements. The message names
            the offending vertex, element or face.
    """

    def __init__(self, vertices, tets, *, name: str = "mesh"):
        self.name = name
        vertices = np.asarray(vertices, dtype=np.float64)
        tets = np.asarray(tets)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise MeshError(f"{name}: vertices must have shape (N, 3), got {vertices.shape}")
        if tets.ndim != 2 or tets.shape[1] != 4:
            raise MeshError(f"{name}: tetrahedra must have shape (M, 4), got {tets.shape}")
        if len(tets) == 0:
            raise MeshError(f"{name}: the mesh has no tetrahedra")
        if not np.issubdtype(tets.dtype, np.integer):
            raise MeshError(f"{name}: tetrahedron indices must be integers, got {tets.dtype}")
        tets = tets.astype(np.int64)
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if len(bad):
            raise MeshError(f"{name}: vertex {bad[0]} has a non-finite coordinate {vertices[bad[0]].tolist()}"
                            f" ({len(bad)} such vertices)")
        out = np.flatnonzero(((tets < 0) | (tets >= len(vertices))).any(axis=1))
        if len(out):
            raise MeshError(f"{name}: element {out[0]} has a vertex index out of range "
                            f"{tets[out[0]].tolist()} (vertex count {len(vertices)})")
        repeated = np.flatnonzero((np.sort(tets, axis=1)[:, 1:] == np.sort(tets, axis=1)[:, :-1]).any(axis=1))
        if len(repeated):
            raise MeshError(f"{name}: element {repeated[0]} repeats a vertex {tets[repeated[0]].tolist()}")
        used = np.zeros(len(vertices), dtype=bool)
        used[tets.ravel()] = True
        unused = np.flatnonzero(~used)
        if len(unused):
            raise MeshError(f"{name}: vertex {unused[0]} is not used by any element "
                            f"({len(unused)} unreferenced vertices)")
        volumes = tet_volumes(vertices, tets)
        degenerate = np.flatnonzero(np.abs(volumes) <= DEGENERATE_TOL * _longest_edges(vertices, tets) ** 3)
        if len(degenerate):
            e = degenerate[0]
            raise MeshError(f"{name}: element {e} {tets[e].tolist()} is degenerate (volume {volumes[e]:.3g} m^3)"
                            f" ({len(degenerate)} degenerate elements)")
        negative = volumes < 0
        self.reoriented_count = int(negative.sum())
        tets[negative] = tets[negative][:, [0, 2, 1, 3]]
        self._check_manifold(tets)
        self.vertices = vertices
        self.tets = tets
        #: file index of each vertex when :meth:`load` dropped some, else None
        self.source_vertex_ids: np.ndarray | None = None
        self._boundary: BoundarySurface | None = None

    @classmethod
    def trusted(cls, vertices: np.ndarray, tets: np.ndarray, *, name: str = "mesh") -> "TetMesh":
        """A mesh from arrays already known to be valid (the topology manager's output),
        without the O(M log M) validation: a cut must cost what it touches, not the mesh size."""
        mesh = cls.__new__(cls)
        mesh.name = name
        mesh.vertices = np.asarray(vertices, dtype=np.float64)
        mesh.tets = np.asarray(tets, dtype=np.int64)
        mesh.reoriented_count = 0
        mesh.source_vertex_ids = None
        mesh._boundary = None
        return mesh

    def _check_manifold(self, tets: np.ndarray) -> None:
        """Every face in at most two elements, on opposite sides (so no element is repeated
        and no two elements overlap across a shared face)."""
        faces = tets[:, TET_FACES].reshape(-1, 3)  # outward oriented, tets positively oriented
        unique, inverse, counts = unique_rows(_face_keys(faces), int(tets.max()) + 1, return_inverse=True,
                                              return_counts=True)
        inverse = inverse.ravel()
        over = np.flatnonzero(counts > 2)
        if len(over):
            owners = np.flatnonzero(inverse == over[0]) // 4
            raise MeshError(f"{self.name}: non-manifold face {unique[over[0]].tolist()} is shared by "
                            f"{counts[over[0]]} elements {owners.tolist()}")
        a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
        parity = ((a > b).astype(int) + (a > c) + (b > c)) % 2  # orientation relative to the sorted key
        shared = np.flatnonzero(counts[inverse] == 2)
        order = shared[np.argsort(inverse[shared], kind="stable")]
        first, second = order[0::2], order[1::2]
        same = np.flatnonzero(parity[first] == parity[second])
        if len(same):
            i, j = first[same[0]] // 4, second[same[0]] // 4
            what = "repeats" if np.array_equal(np.sort(tets[i]), np.sort(tets[j])) else "overlaps"
            raise MeshError(f"{self.name}: element {j} {what} element {i} (both on the same side of face "
                            f"{unique[inverse[first[same[0]]]].tolist()})")

    def volumes(self) -> np.ndarray:
        """Rest volumes (m^3) of the elements, all positive."""
        return tet_volumes(self.vertices, self.tets)

    def boundary(self) -> BoundarySurface:
        """The boundary triangles (faces owned by exactly one element), outward oriented."""
        if self._boundary is None:
            faces = self.tets[:, TET_FACES].reshape(-1, 3)
            _, inverse, counts = unique_rows(_face_keys(faces), len(self.vertices), return_inverse=True,
                                             return_counts=True)
            triangles = faces[counts[inverse.ravel()] == 1]
            vertex_ids, local = np.unique(triangles, return_inverse=True)
            self._boundary = BoundarySurface(triangles, vertex_ids, local.reshape(-1, 3))
        return self._boundary

    def linear(self) -> "TetMesh":
        """The mesh of linear elements: this one (as ``QuadraticTetMesh.linear`` gives its
        corners), so code that needs corners takes ``mesh.linear()`` of either."""
        return self

    def edges(self) -> np.ndarray:
        """(E, 2) unique undirected edges, each as (low, high) vertex indices."""
        pairs = self.tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]].reshape(-1, 2)
        return unique_rows(np.sort(pairs, axis=1), len(self.vertices))

    def mean_edge_length(self) -> float:
        """Mean rest length (m) of the unique edges."""
        e = self.edges()
        return float(np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1).mean())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "TetMesh":
        """Read a tetrahedral mesh from any format meshio reads (.msh, .vtu, .vtk, .mesh, ...).

        Every ``tetra`` cell block is used; other cell types (surface triangles, lines) are
        ignored. Vertices only they reference are dropped, and then ``source_vertex_ids[i]`` is
        the file's index of vertex ``i`` (``None`` when the numbering is the file's). Vertices no
        cell uses are dropped too, with a :class:`~wcut.errors.MeshNotice`. gmsh's first
        format (``$NOD``/``$ELM``, SOFA's ``.msh`` files) is read by :mod:`wcut.gmsh_v1`.
        """
        path = os.fspath(path)
        data = read_meshio(path)
        blocks = [block.data for block in data.cells if block.type == "tetra"]
        if not blocks:
            kinds = sorted({block.type for block in data.cells})
            raise MeshError(f"{path}: no tetrahedra in the file (cell types: {', '.join(kinds) or 'none'})")
        tets = np.concatenate(blocks).astype(np.int64)
        points = np.asarray(data.points, dtype=np.float64)
        if points.ndim == 2 and points.shape[1] == 2:
            raise MeshError(f"{path}: the mesh is two-dimensional")
        name = os.path.basename(path)
        if tets.min() < 0 or tets.max() >= len(points):
            raise MeshError(f"{name}: element index out of range (vertex count {len(points)})")
        notice_unused_vertices(name, data)
        used = np.unique(tets)
        source_ids = None
        if len(used) < len(points):  # vertices of no cell or of surface or line cells only: not part of the solid
            remap = np.full(len(points), -1, dtype=np.int64)
            remap[used] = np.arange(len(used))
            points, tets, source_ids = points[used], remap[tets], used
        mesh = cls(points, tets, name=name)
        mesh.source_vertex_ids = source_ids
        return mesh

    def save(self, path: str | os.PathLike) -> None:
        """Write the mesh with meshio (format from the extension, one of
        :data:`VOLUME_MESH_FORMATS`), atomically."""
        import meshio

        check_mesh_format(path)

        from .io import atomic_path

        with atomic_path(path) as tmp:
            meshio.write(tmp, meshio.Mesh(self.vertices, [("tetra", self.tets)]))


def beam(nx: int, ny: int, nz: int, size=(1.0, 1.0, 1.0), *, origin=(0.0, 0.0, 0.0),
         tets_per_hex: int = 5) -> TetMesh:
    """A box of ``nx * ny * nz`` hexahedra, each split into tetrahedra.

    Args:
        nx, ny, nz: hexahedra along x, y and z.
        size: box extent (m) along x, y and z.
        origin: the box's lowest corner (m).
        tets_per_hex: 5 (a central regular-shaped tetrahedron and four corners, with the split
            mirrored on alternate cells so faces conform) or 6 (the Kuhn split along the main
            diagonal, the same in every cell).

    Returns:
        A mesh of ``(nx+1)(ny+1)(nz+1)`` vertices and ``tets_per_hex * nx * ny * nz`` tetrahedra.
        Vertex (i, j, k) has index ``(i * (ny + 1) + j) * (nz + 1) + k``.
    """
    if min(nx, ny, nz) < 1:
        raise MeshError(f"beam: cell counts must be at least 1, got ({nx}, {ny}, {nz})")
    if tets_per_hex not in (5, 6):
        raise MeshError(f"beam: tets_per_hex must be 5 or 6, got {tets_per_hex}")
    size = np.asarray(size, dtype=np.float64)
    if size.shape != (3,) or not np.all(size > 0):
        raise MeshError(f"beam: size must be three positive lengths, got {size.tolist()}")
    axes = [np.linspace(0.0, s, n + 1) for s, n in zip(size, (nx, ny, nz))]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3) + np.asarray(origin, float)

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()

    def corner(a, b, c):
        return ((i + a) * (ny + 1) + (j + b)) * (nz + 1) + (k + c)

    # corners[:, 4a + 2b + c] is the corner at offset (a, b, c)
    corners = np.stack([corner(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)], axis=1)
    if tets_per_hex == 5:
        even = np.array([[0, 4, 2, 1], [6, 2, 4, 7], [5, 1, 7, 4], [3, 7, 1, 2], [1, 2, 4, 7]])
        odd = np.array([[4, 0, 5, 6], [2, 6, 3, 0], [7, 5, 6, 3], [1, 3, 5, 0], [0, 3, 6, 5]])
        parity = ((i + j + k) % 2 == 0)[:, None, None]
        local = np.where(parity, even[None], odd[None])
        tets = np.take_along_axis(corners[:, None, :], local, axis=2)
    else:
        # Kuhn split: six tetrahedra around the diagonal from corner 0 to corner 7.
        paths = np.array([[0, 4, 6, 7], [0, 4, 5, 7], [0, 2, 6, 7], [0, 2, 3, 7], [0, 1, 5, 7], [0, 1, 3, 7]])
        tets = corners[:, paths]
    return TetMesh(grid, tets.reshape(-1, 4), name=f"beam({nx}, {ny}, {nz})")


def perturbed(mesh: TetMesh, scale: float, seed: int = 0) -> TetMesh:
    """``mesh`` with its interior vertices moved at random, for trying code on poor elements.

    Each vertex off the boundary moves by up to ``scale`` times the mean edge length along
    each axis; the move of every vertex of an element it would fold (volume below
    ``DEGENERATE_TOL`` of its longest edge cubed) is halved until none folds. Scales of
    0.3 and 1 on a ``beam`` give worst dihedral angles of some 10 and 0.6 degrees; the
    boundary, and so the volume, stay."""
    rng = np.random.default_rng(seed)
    x, tets = mesh.vertices, mesh.tets
    move = rng.uniform(-scale, scale, x.shape) * mesh.mean_edge_length()
    move[mesh.boundary().vertex_ids] = 0.0
    for _ in range(60):
        folded = tet_volumes(x + move, tets) <= DEGENERATE_TOL * _longest_edges(x + move, tets) ** 3
        if not folded.any():
            break
        move[np.unique(tets[folded])] *= 0.5
    return TetMesh(x + move, tets, name=f"perturbed({mesh.name}, {scale:g})")


def dihedral_angles(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(M, 6) interior dihedral angles (degrees) of tetrahedra at their six edges."""
    X = vertices[tets]
    normals = np.stack([np.cross(X[:, f[1]] - X[:, f[0]], X[:, f[2]] - X[:, f[0]]) for f in TET_FACES], axis=1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    # faces i and j meet at the edge of the two vertices that are neither i nor j
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    cos = np.stack([-np.einsum("mk,mk->m", normals[:, i], normals[:, j]) for i, j in pairs], axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


# ---------------------------------------------------------------------------------------------
# Quadratic triangle shells (thesis 6.2)
#
# A 6-node triangle is VTK's / meshio's ``triangle6``: corners 0, 1, 2, then the nodes of the
# edges (0, 1), (1, 2), (2, 0). In barycentric coordinates ``L = (L0, L1, L2)`` the shape
# functions are ``L_k (2 L_k - 1)`` at corner k and ``4 L_i L_j`` at the node of edge (i, j);
# the reference coordinates are ``(r, s) = (L1, L2)``, on the reference triangle of area 1/2.

#: Relative corner area below which a triangle counts as degenerate: A < TRI_DEGENERATE_TOL * l^2,
#: with l the longest corner edge (an equilateral triangle has 0.433).
TRI_DEGENERATE_TOL = 1e-10

#: A curved triangle folds when its Jacobian (relative to the corner normal) falls to this
#: fraction of a straight element's (twice the corner area) at a Gauss point or node.
TRI_FOLD_TOL = 1e-6

#: Mesh file formats whose meshio writers keep ``triangle6`` cells (the others drop them
#: silently), and the meshio format to write for each.
_TRIANGLE6_FORMATS = {".vtu": "vtu", ".vtk": "vtk", ".msh": "gmsh"}

#: Diagonal patterns of the sheet generators.
SHEET_PATTERNS = ("alternate", "right")


def _index_array(cells, columns: int, vertex_count: int, name: str, what: str) -> np.ndarray:
    """``cells`` as an (M, columns) int64 array of indices into ``vertex_count`` vertices, or a
    MeshError that names the first bad row."""
    cells = np.asarray(cells)
    if cells.ndim != 2 or cells.shape[1] != columns:
        raise MeshError(f"{name}: {what} must have shape (M, {columns}), got {cells.shape}")
    if len(cells) == 0:
        raise MeshError(f"{name}: the mesh has no triangles")
    if not np.issubdtype(cells.dtype, np.integer):
        raise MeshError(f"{name}: triangle indices must be integers, got {cells.dtype}")
    cells = cells.astype(np.int64)
    out = np.flatnonzero(((cells < 0) | (cells >= vertex_count)).any(axis=1))
    if len(out):
        raise MeshError(f"{name}: triangle {out[0]} has a node index out of range {cells[out[0]].tolist()} "
                        f"(vertex count {vertex_count})")
    return cells


def _vertex_array(vertices, name: str) -> np.ndarray:
    """``vertices`` as a finite (N, 3) float64 array, or a MeshError naming the first bad vertex."""
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (N, 3), got {vertices.shape}")
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise MeshError(f"{name}: vertex {bad[0]} has a non-finite coordinate {vertices[bad[0]].tolist()}"
                        f" ({len(bad)} such vertices)")
    return vertices


class ShellMesh(_VertexQueries):
    """A validated mesh of quadratic (6-node) triangles: a thin shell or membrane in its rest
    configuration (thesis 6.2).

    Args:
        vertices: (N, 3) rest positions of all nodes (corners and edge nodes), in metres.
        triangles: (M, 6) node indices in ``triangle6`` order: corners 0, 1, 2, then the nodes
            of the edges (0, 1), (1, 2), (2, 0).
        name: used in error messages (a file name, a generator).

    Raises:
        MeshError: the message names the offending vertex, triangle or edge, for non-finite
            coordinates; bad shapes or indices; a node repeated in a triangle or used by none;
            a node that is both a corner and an edge node; a degenerate corner triangle (area
            below :data:`TRI_DEGENERATE_TOL` times its longest edge squared); a repeated
            triangle; a corner edge in more than two triangles (non-manifold), with different
            edge nodes in its two triangles, or an edge node on two corner edges (the mesh does
            not conform); two triangles that traverse their shared edge in the same direction
            (inconsistent orientation: nothing is reoriented, but either consistent orientation
            is accepted); or a curved triangle whose Jacobian relative to its corner normal is
            not positive at a Gauss point or node (it folds).
    """

    def __init__(self, vertices, triangles, *, name: str = "mesh"):
        self.name = name
        vertices = _vertex_array(vertices, name)
        triangles = _index_array(triangles, 6, len(vertices), name, "quadratic triangles")
        self._check_nodes(triangles, len(vertices))
        self._check_corner_triangles(vertices, triangles)
        self._check_edges(triangles, len(vertices))
        self._check_jacobians(vertices, triangles)
        self.vertices = vertices
        self.triangles = triangles
        #: file index of each vertex when :meth:`load` renumbered them, else None
        self.source_vertex_ids: np.ndarray | None = None

    @classmethod
    def trusted(cls, vertices: np.ndarray, triangles: np.ndarray, *, name: str = "mesh") -> "ShellMesh":
        """A mesh from arrays already known to be valid (the topology manager's output), without
        validation: a crack step must cost what it touches, not the mesh size."""
        mesh = cls.__new__(cls)
        mesh.name = name
        mesh.vertices = np.asarray(vertices, dtype=np.float64)
        mesh.triangles = np.asarray(triangles, dtype=np.int64)
        mesh.source_vertex_ids = None
        return mesh

    @classmethod
    def from_linear(cls, vertices, triangles, *, name: str = "mesh") -> "ShellMesh":
        """The quadratic mesh of linear triangles (M, 3) with straight edges: vertices 0..N-1
        are the corners, unchanged, then one node per corner edge at its midpoint, numbered in
        order of first appearance (triangle by triangle, edges (0, 1), (1, 2), (2, 0)). A
        shared edge gets one node."""
        vertices = _vertex_array(vertices, name)
        triangles = _index_array(triangles, 3, len(vertices), name, "triangles")
        n = len(vertices)
        pairs = triangles[:, shell.EDGES].reshape(-1, 2)
        keys = pairs.min(axis=1) * n + pairs.max(axis=1)
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        # np.unique numbers edges by key; renumber them by where they first appear
        rank = np.empty(len(first), dtype=np.int64)
        rank[np.argsort(first)] = np.arange(len(first))
        firsts = np.sort(first)
        midpoints = 0.5 * (vertices[pairs[firsts, 0]] + vertices[pairs[firsts, 1]])
        six = np.concatenate([triangles, n + rank[inverse.ravel()].reshape(-1, 3)], axis=1)
        return cls(np.concatenate([vertices, midpoints]), six, name=name)

    # -- validation ---------------------------------------------------------------------------

    def _check_nodes(self, triangles: np.ndarray, count: int) -> None:
        """No node twice in a triangle, every node used, and no node both a corner and an
        edge node (a corner's shape function is not an edge node's)."""
        ordered = np.sort(triangles, axis=1)
        repeated = np.flatnonzero((ordered[:, 1:] == ordered[:, :-1]).any(axis=1))
        if len(repeated):
            t = repeated[0]
            raise MeshError(f"{self.name}: triangle {t} repeats a node {triangles[t].tolist()}")
        used = np.zeros(count, dtype=bool)
        used[triangles.ravel()] = True
        unused = np.flatnonzero(~used)
        if len(unused):
            raise MeshError(f"{self.name}: vertex {unused[0]} is not used by any triangle "
                            f"({len(unused)} unreferenced vertices)")
        both = np.intersect1d(triangles[:, :3], triangles[:, 3:])
        if len(both):
            v = both[0]
            as_corner = np.flatnonzero((triangles[:, :3] == v).any(axis=1))[0]
            as_edge = np.flatnonzero((triangles[:, 3:] == v).any(axis=1))[0]
            raise MeshError(f"{self.name}: node {v} is both a corner (of triangle {as_corner}) and an edge node "
                            f"(of triangle {as_edge})")

    def _check_corner_triangles(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        """No degenerate corner triangle, and no two triangles on the same three corners."""
        areas = 0.5 * np.linalg.norm(shell.corner_normals(vertices, triangles), axis=1)
        x = vertices[triangles[:, :3]]
        longest = np.max([np.linalg.norm(x[:, a] - x[:, b], axis=1) for a, b in shell.EDGES], axis=0)
        degenerate = np.flatnonzero(areas <= TRI_DEGENERATE_TOL * longest**2)
        if len(degenerate):
            t = degenerate[0]
            raise MeshError(f"{self.name}: triangle {t} {triangles[t].tolist()} is degenerate (corner area "
                            f"{areas[t]:.3g} m^2, longest edge {longest[t]:.3g} m) ({len(degenerate)} degenerate "
                            f"triangles)")
        _, first, inverse = np.unique(np.sort(triangles[:, :3], axis=1), axis=0, return_index=True,
                                      return_inverse=True)
        repeats = np.flatnonzero(first[inverse.ravel()] != np.arange(len(triangles)))
        if len(repeats):
            t = repeats[0]
            raise MeshError(f"{self.name}: triangle {t} repeats triangle {first[inverse.ravel()[t]]} "
                            f"(corners {triangles[t, :3].tolist()})")

    def _check_edges(self, triangles: np.ndarray, count: int) -> None:
        """Every corner edge in at most two triangles, with one edge node for both, an edge
        node on one edge only, and the two triangles of an edge traversing it in opposite
        directions (consistent orientation, so normals agree across the edge)."""
        directed = triangles[:, shell.EDGES].reshape(-1, 2)  # corner pairs as each triangle traverses them
        nodes = triangles[:, 3:].reshape(-1)
        low, high = directed.min(axis=1), directed.max(axis=1)
        keys, first, inverse, counts = np.unique(low * count + high, return_index=True, return_inverse=True,
                                                 return_counts=True)
        inverse = inverse.ravel()

        def edge(k: int) -> str:
            return f"({keys[k] // count}, {keys[k] % count})"

        over = np.flatnonzero(counts > 2)
        if len(over):
            owners = np.flatnonzero(inverse == over[0]) // 3
            raise MeshError(f"{self.name}: non-manifold edge {edge(over[0])} is shared by {counts[over[0]]} "
                            f"triangles {owners.tolist()} (at most two)")
        shared = np.flatnonzero(counts[inverse] == 2)
        order = shared[np.argsort(inverse[shared], kind="stable")]
        one, two = order[0::2], order[1::2]
        differ = np.flatnonzero(nodes[one] != nodes[two])
        if len(differ):
            a, b = one[differ[0]], two[differ[0]]
            raise MeshError(f"{self.name}: triangles {a // 3} and {b // 3} share the edge {edge(inverse[a])} "
                            f"but not its edge node ({nodes[a]} and {nodes[b]}): the mesh does not conform")
        node_of_edge = nodes[first]
        values, edge_counts = np.unique(node_of_edge, return_counts=True)
        if (edge_counts > 1).any():
            v = values[edge_counts > 1][0]
            on = np.flatnonzero(node_of_edge == v)
            raise MeshError(f"{self.name}: node {v} is the edge node of two edges {edge(on[0])} (triangle "
                            f"{first[on[0]] // 3}) and {edge(on[1])} (triangle {first[on[1]] // 3})")
        forward = directed[:, 0] < directed[:, 1]
        same = np.flatnonzero(forward[one] == forward[two])
        if len(same):
            a, b = one[same[0]], two[same[0]]
            raise MeshError(f"{self.name}: triangles {a // 3} and {b // 3} are inconsistently oriented: both "
                            f"traverse their shared edge {edge(inverse[a])} from {directed[a, 0]} to "
                            f"{directed[a, 1]}")

    def _check_jacobians(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        at_gauss, at_nodes = shell.jacobians(vertices, triangles)
        worst = np.minimum(at_gauss.min(axis=1), at_nodes.min(axis=1))
        straight = np.linalg.norm(shell.corner_normals(vertices, triangles), axis=1)
        folded = np.flatnonzero(worst <= TRI_FOLD_TOL * straight)
        if len(folded):
            t = folded[0]
            raise MeshError(f"{self.name}: curved triangle {t} {triangles[t].tolist()} folds: its Jacobian "
                            f"relative to the corner normal is {worst[t]:.3g} m^2 at a Gauss point or node "
                            f"({straight[t]:.3g} m^2 if straight; {len(folded)} such triangles)")

    # -- queries ------------------------------------------------------------------------------

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)

    @property
    def tet_count(self) -> int:
        # A shell has no tetrahedra: raising AttributeError also makes hasattr(mesh, "tet_count")
        # false, so code that dispatches on it does not take a shell for a volume mesh.
        raise AttributeError(f"{self.name}: a ShellMesh has triangles, not tetrahedra (see triangle_count)")

    @property
    def corner_ids(self) -> np.ndarray:
        """Sorted indices of the corner vertices (the others are edge nodes)."""
        return np.unique(self.triangles[:, :3])

    def areas(self) -> np.ndarray:
        """Rest areas (m^2) of the curved triangles: exact for flat ones (see :data:`wcut.shell.AREA_POINTS`)."""
        return shell.areas(self.vertices, self.triangles)

    def area(self) -> float:
        """Total rest area (m^2)."""
        return float(self.areas().sum())

    def edges(self) -> np.ndarray:
        """(E, 2) unique corner edges, each as (low, high) vertex indices."""
        return np.unique(np.sort(self.triangles[:, shell.EDGES].reshape(-1, 2), axis=1), axis=0)

    def mean_edge_length(self) -> float:
        """Mean straight length (m) of the unique corner edges."""
        e = self.edges()
        return float(np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1).mean())

    def boundary_edges(self) -> np.ndarray:
        """(E, 3) the corner edges used by one triangle, as (corner a, corner b, edge node) with
        a -> b the direction their triangle traverses them (triangle by triangle, edges (0, 1),
        (1, 2), (2, 0)). On a counter-clockwise sheet the region lies left of a -> b."""
        directed = self.triangles[:, shell.EDGES].reshape(-1, 2)
        nodes = self.triangles[:, 3:].reshape(-1, 1)
        keys = np.sort(directed, axis=1)
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        once = counts[inverse.ravel()] == 1
        return np.concatenate([directed, nodes], axis=1)[once]

    def linear_triangles(self) -> np.ndarray:
        """(4M, 3) the mesh split into linear triangles at the edge nodes, four per element in
        the order of :data:`shell.SUBTRIANGLES`, elements in order; oriented as the elements."""
        return self.triangles[:, shell.SUBTRIANGLES].reshape(-1, 3)

    def surface_tessellation(self, level: int = 2):
        """The curved sheet as flat triangles for rendering: each element split into ``4**level``
        (a :class:`wcut.quadratic.SurfaceTessellation`)."""
        from .quadratic import SurfaceTessellation

        return SurfaceTessellation.of_quadratic(self.triangles, self.vertex_count, level)

    # -- I/O ----------------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ShellMesh":
        """Read a triangle mesh from any format meshio reads (.vtu, .vtk, .msh, .obj, ...).

        The file's ``triangle6`` cells are used as they are; a file without them has its linear
        ``triangle`` cells made quadratic with straight edges (:meth:`from_linear`). Other
        cells are ignored. Two-dimensional points are put in the plane z = 0. Vertices the
        triangles do not use are dropped, and then ``source_vertex_ids[i]`` is the file's index
        of vertex ``i`` (``None`` when the numbering is the file's). For linear triangles it is
        always set and covers the corners only: the edge nodes made after them are in no file.
        """
        path = os.fspath(path)
        data = read_meshio(path)
        quadratic = [np.asarray(b.data, dtype=np.int64) for b in data.cells if b.type == "triangle6"]
        linear = [np.asarray(b.data, dtype=np.int64) for b in data.cells if b.type == "triangle"]
        if not quadratic and not linear:
            kinds = sorted({b.type for b in data.cells})
            raise MeshError(f"{path}: no triangles (triangle6 or triangle) in the file (cell types: "
                            f"{', '.join(kinds) or 'none'})")
        name = os.path.basename(path)
        cells = np.concatenate(quadratic or linear)
        points = np.asarray(data.points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] not in (2, 3):
            raise MeshError(f"{name}: points must be two- or three-dimensional, got shape {points.shape}")
        if points.shape[1] == 2:  # a flat sheet
            points = np.concatenate([points, np.zeros((len(points), 1))], axis=1)
        if cells.min() < 0 or cells.max() >= len(points):
            raise MeshError(f"{name}: triangle index out of range (vertex count {len(points)})")
        used = np.unique(cells)
        remap = np.full(len(points), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        if quadratic:
            mesh = cls(points[used], remap[cells], name=name)
            mesh.source_vertex_ids = used if len(used) < len(points) else None
        else:
            mesh = cls.from_linear(points[used], remap[cells], name=name)
            mesh.source_vertex_ids = used
        return mesh

    def save(self, path: str | os.PathLike) -> None:
        """Write the mesh (``triangle6`` cells) with meshio, atomically, as .vtu, .vtk or .msh
        (gmsh): the other formats meshio writes would drop 6-node triangles.

        Raises:
            ExportError: another extension, or the file cannot be written.
        """
        import meshio

        from .errors import ExportError
        from .io import atomic_path

        suffix = os.path.splitext(os.fspath(path))[1].lower()
        if suffix not in _TRIANGLE6_FORMATS:
            raise ExportError(f"{os.fspath(path)}: cannot write 6-node triangles as '{suffix}': use "
                              f"{', '.join(_TRIANGLE6_FORMATS)}")
        mesh = meshio.Mesh(self.vertices, [("triangle6", self.triangles)])
        # the gmsh writer prints warnings about tags a shell does not have
        with atomic_path(path) as tmp, contextlib.redirect_stdout(io.StringIO()), \
                contextlib.redirect_stderr(io.StringIO()):
            meshio.write(tmp, mesh, file_format=_TRIANGLE6_FORMATS[suffix])


# -- sheet generators -------------------------------------------------------------------------


def _cell_counts(function: str, **counts) -> None:
    for label, value in counts.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise MeshError(f"{function}: {label} must be an integer of at least 1, got {value!r}")


def _lengths(function: str, label: str, value, count: int) -> np.ndarray:
    """``value`` as ``count`` positive finite lengths (m), or a MeshError."""
    try:
        lengths = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        lengths = np.array([np.nan])
    if lengths.shape != (count,) or not np.all(np.isfinite(lengths) & (lengths > 0)):
        what = "a positive length" if count == 1 else f"{count} positive lengths"
        raise MeshError(f"{function}: {label} must be {what} (m), got {value!r}")
    return lengths


def _origin(function: str, origin) -> np.ndarray:
    """``origin`` (x, y) or (x, y, z) in metres as a 3-vector, or a MeshError."""
    try:
        point = np.asarray(origin, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        point = np.array([np.nan])
    if len(point) not in (2, 3) or not np.isfinite(point).all():
        raise MeshError(f"{function}: origin must be two or three finite coordinates (m), got {origin!r}")
    return np.concatenate([point, [0.0]])[:3]


def _pattern(function: str, pattern: str) -> str:
    if pattern not in SHEET_PATTERNS:
        raise MeshError(f"{function}: pattern must be one of {', '.join(SHEET_PATTERNS)}, got {pattern!r}")
    return pattern


def _grid_points(nx: int, ny: int, size: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The (nx+1)(ny+1) grid points of a sheet in the plane z = origin z; point (i, j) has
    index ``i * (ny + 1) + j``."""
    x, y = np.meshgrid(np.linspace(0.0, size[0], nx + 1), np.linspace(0.0, size[1], ny + 1), indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1) + origin


def _grid_triangles(nx: int, ny: int, pattern: str, cells: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Two counter-clockwise linear triangles (seen from +z) per grid cell, cell by cell.

    ``cells`` (C, 2) selects cells (i, j) (default all, i major). The diagonal of cell (i, j)
    goes from (i, j) to (i+1, j+1) (``"right"``) or, with ``"alternate"``, on cells with odd
    i + j from (i+1, j) to (i, j+1): the criss-cross pattern gives no direction preference, so
    cracks that follow edges are not biased. Returns the triangles (2C, 3) and the cell row j
    of each (2C,)."""
    if cells is None:
        cells = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), axis=-1).reshape(-1, 2)
    i, j = cells[:, 0], cells[:, 1]
    v00, v01 = i * (ny + 1) + j, i * (ny + 1) + j + 1
    v10, v11 = v00 + ny + 1, v01 + ny + 1
    main = np.stack([np.stack([v00, v10, v11], axis=1), np.stack([v00, v11, v01], axis=1)], axis=1)
    anti = np.stack([np.stack([v00, v10, v01], axis=1), np.stack([v10, v11, v01], axis=1)], axis=1)
    flip = ((i + j) % 2 == 1) if pattern == "alternate" else np.zeros(len(i), dtype=bool)
    triangles = np.where(flip[:, None, None], anti, main).reshape(-1, 3)
    return triangles, np.repeat(j, 2)


def _compact(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points no triangle uses dropped, the others renumbered in their order."""
    used = np.unique(triangles)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[triangles]


def rectangle_sheet(nx: int, ny: int, size=(1.0, 1.0), *, origin=(0.0, 0.0, 0.0),
                    pattern: str = "alternate") -> ShellMesh:
    """A flat rectangular sheet of ``nx * ny`` cells, each split into two quadratic triangles
    with straight edges, in the plane z = origin z, counter-clockwise seen from +z (normal +z).

    Args:
        nx, ny: cells along x and y.
        size: sheet extent (m) along x and y.
        origin: the sheet's lowest corner (m), (x, y) or (x, y, z).
        pattern: ``"alternate"`` (diagonals alternate from cell to cell: a criss-cross with no
            preferred crack direction) or ``"right"`` (every diagonal from lower left to upper
            right).

    Returns:
        A mesh whose corner (i, j) at ``origin + (i w / nx, j h / ny, 0)`` is vertex
        ``i * (ny + 1) + j``; the edge nodes follow (:meth:`ShellMesh.from_linear`).
    """
    _cell_counts("rectangle_sheet", nx=nx, ny=ny)
    size = _lengths("rectangle_sheet", "size", size, 2)
    points = _grid_points(nx, ny, size, _origin("rectangle_sheet", origin))
    triangles, _ = _grid_triangles(nx, ny, _pattern("rectangle_sheet", pattern))
    return ShellMesh.from_linear(points, triangles, name="rectangle_sheet")


def l_shape_sheet(n: int, size: float = 1.0, *, origin=(0.0, 0.0, 0.0), pattern: str = "alternate") -> ShellMesh:
    """A flat L-shaped sheet (thesis figure 6.12): a square of side ``size`` (m) made of
    ``2n x 2n`` cells without its top-right quadrant of ``n x n`` cells, each cell split into two
    quadratic triangles with straight edges, counter-clockwise seen from +z, in the plane
    z = origin z. The re-entrant corner, where stresses concentrate, is the vertex at
    ``origin + (size / 2, size / 2, 0)``.

    Args:
        n: cells along half a side.
        size: side of the square (m).
        origin: the square's lowest corner (m), (x, y) or (x, y, z).
        pattern: diagonal pattern, as in :func:`rectangle_sheet`.

    Returns:
        A mesh of ``6 n^2`` triangles; the corners are the grid points of the L in the order of
        :func:`rectangle_sheet` (those of the removed quadrant skipped), then the edge nodes.
    """
    _cell_counts("l_shape_sheet", n=n)
    side = _lengths("l_shape_sheet", "size", size, 1)[0]
    points = _grid_points(2 * n, 2 * n, np.array([side, side]), _origin("l_shape_sheet", origin))
    cells = np.stack(np.meshgrid(np.arange(2 * n), np.arange(2 * n), indexing="ij"), axis=-1).reshape(-1, 2)
    cells = cells[(cells[:, 0] < n) | (cells[:, 1] < n)]
    triangles, _ = _grid_triangles(2 * n, 2 * n, _pattern("l_shape_sheet", pattern), cells)
    points, triangles = _compact(points, triangles)
    return ShellMesh.from_linear(points, triangles, name="l_shape_sheet")


def precut_sheet(nx: int, ny: int, size=(1.0, 1.0), notch_length: float = 0.5, *, origin=(0.0, 0.0, 0.0),
                 pattern: str = "alternate") -> ShellMesh:
    """A flat rectangular sheet with a precut crack (thesis figure 6.12): a straight slit of
    zero width from the middle of the left side (y = h / 2) along +x.

    The slit follows grid edges, so its length is ``notch_length`` rounded to the nearest whole
    number of cells, ``k = floor(notch_length / (w / nx) + 1/2)``, and its tip is the vertex at
    ``origin + (k w / nx, h / 2, 0)``. The grid vertices on the slit other than the tip are
    duplicated: the triangles below the slit use the originals, those above the copies, so the
    two sides are not connected across it. The tip is shared. Otherwise as
    :func:`rectangle_sheet` (counter-clockwise seen from +z, plane z = origin z).

    Args:
        nx, ny: cells along x and y; ``ny`` must be even (the slit lies on a grid line).
        size: sheet extent (w, h) in metres.
        notch_length: slit length (m); it must round to at least one cell and end inside the
            sheet (``1 <= k <= nx - 1``).
        origin: the sheet's lowest corner (m), (x, y) or (x, y, z).
        pattern: diagonal pattern, as in :func:`rectangle_sheet`.

    Returns:
        A mesh whose corners are the grid points of :func:`rectangle_sheet`, then the ``k``
        copies of the slit vertices at (i w / nx, h / 2), i = 0..k-1, then the edge nodes.
    """
    function = "precut_sheet"
    _cell_counts(function, nx=nx, ny=ny)
    if ny % 2:
        raise MeshError(f"{function}: ny must be even so that the slit at y = h/2 is a grid line, got {ny}")
    size = _lengths(function, "size", size, 2)
    notch = _lengths(function, "notch_length", notch_length, 1)[0]
    width = size[0] / nx
    cells = int(np.floor(notch / width + 0.5))
    if notch >= size[0] or cells >= nx:
        raise MeshError(f"{function}: notch_length {notch:g} m is too long: rounded to whole cells of {width:g} m "
                        f"it must end inside the sheet of width {size[0]:g} m (at most {nx - 1} cells)")
    if cells < 1:
        raise MeshError(f"{function}: notch_length {notch:g} m is shorter than half a cell ({width / 2:g} m)")
    points = _grid_points(nx, ny, size, _origin(function, origin))
    triangles, rows = _grid_triangles(nx, ny, _pattern(function, pattern))
    slit = np.arange(cells) * (ny + 1) + ny // 2  # grid vertices (i, ny/2), i < k: the tip is not cut
    copies = np.arange(len(points))
    copies[slit] = len(points) + np.arange(cells)
    above = rows >= ny // 2
    triangles[above] = copies[triangles[above]]
    return ShellMesh.from_linear(np.concatenate([points, points[slit]]), triangles, name=function)
