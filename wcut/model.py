"""Model, State and Control of a corotational object (names as in Newton).

- :class:`Model` holds the rest data as flat ``wp.array``s on one device: rest positions,
  lumped masses, fixed vertices, element connectivity, shape-function gradients, volumes and
  stiffness, attachment springs. It is built from a tetrahedral mesh (:class:`wcut.mesh.TetMesh`,
  :class:`wcut.quadratic.QuadraticTetMesh`) or a thin shell (:class:`wcut.mesh.ShellMesh`) and
  material parameters, once per topology.
- :class:`State` holds what changes every step: positions, velocities, external forces and
  the element rotations (warm start of the polar decomposition).
- :class:`Control` holds what the user drives besides forces: attachment targets.

All arrays are public so a user's own Warp kernels can read and write them between steps.
Units are SI: metres, kilograms, seconds, newtons, pascals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from . import p2, shell
from .errors import ModelError
from .mesh import ShellMesh, TetMesh, edge_matrices


def lame_parameters(youngs_modulus, poisson_ratio):
    """Lame parameters (mu, lambda) in Pa from Young's modulus (Pa) and Poisson's ratio."""
    E = np.asarray(youngs_modulus, dtype=np.float64)
    nu = np.asarray(poisson_ratio, dtype=np.float64)
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def _number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ModelError(f"{name}: expected a number, got {value!r}")
    return float(value)


def _per_element(value, count: int, name: str, lower: float, upper: float) -> np.ndarray:
    """A number or one number per element, each in the open interval (lower, upper)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelError(f"{name}: expected a number or {count} numbers, got {value!r}") from None
    if arr.ndim == 0:
        arr = np.full(count, float(arr))
    if arr.shape != (count,):
        raise ModelError(f"{name}: expected a number or {count} values (one per element), got shape {arr.shape}")
    bad = np.flatnonzero(~(np.isfinite(arr) & (arr > lower) & (arr < upper)))
    if len(bad):
        where = f"element {bad[0]} has" if np.ndim(value) else "got"
        raise ModelError(f"{name}: {where} {arr[bad[0]]}, expected a value in ({lower}, {upper})")
    return arr


def _vertex_indices(value, count: int, name: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.size == 0:
        return np.zeros(0, dtype=np.int64)
    if arr.dtype == bool:
        if arr.shape != (count,):
            raise ModelError(f"{name}: a mask needs {count} entries, got shape {arr.shape}")
        return np.flatnonzero(arr)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ModelError(f"{name}: expected integer vertex indices or a boolean mask, got {arr.dtype}")
    arr = arr.astype(np.int64).reshape(-1)
    bad = np.flatnonzero((arr < 0) | (arr >= count))
    if len(bad):
        raise ModelError(f"{name}: vertex index {arr[bad[0]]} out of range 0..{count - 1}")
    return arr


#: The largest gravity (m/s^2) a model takes: a centrifuge's 1e5 g. Beyond, float32 arithmetic
#: overflows (1e300 becomes infinite) long before anything physical happens.
MAX_GRAVITY = 1.0e6


@dataclass
class Attachments:
    """Attachment springs from points of the object to targets (targets live in Control).

    Attachment ``s`` pulls the point ``sum_j weights[s, j] * x[indices[s, j]]`` towards
    ``Control.attachment_target[s]`` with ``stiffness[s]`` (N/m): grabbing tools and, later,
    the coupling to video features.

    Attributes:
        indices: (S, 4) vertex indices; unused slots repeat a valid index with weight 0.
        weights: (S, 4) barycentric weights (sum 1 for a point inside an element).
        stiffness: (S,) spring stiffness in N/m.
    """

    indices: np.ndarray
    weights: np.ndarray
    stiffness: np.ndarray

    def __post_init__(self):
        try:
            self.indices = np.asarray(self.indices)
            self.weights = np.asarray(self.weights, dtype=np.float64)
            self.stiffness = np.asarray(self.stiffness, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise ModelError(f"attachments: {exc}") from None
        count = len(self.stiffness)
        if self.indices.shape != (count, 4) or self.weights.shape != (count, 4):
            raise ModelError(f"attachments: indices and weights must have shape ({count}, 4) for {count} "
                             f"stiffness values, got {self.indices.shape} and {self.weights.shape}")
        if count and not np.issubdtype(self.indices.dtype, np.integer):
            raise ModelError(f"attachments: indices must be integers, got {self.indices.dtype}")
        self.indices = self.indices.astype(np.int32)
        bad = np.flatnonzero(~np.isfinite(self.weights).all(axis=1) | ~np.isfinite(self.stiffness)
                             | (self.stiffness < 0))
        if len(bad):
            raise ModelError(f"attachments: attachment {bad[0]} has a non-finite weight or a negative or "
                             f"non-finite stiffness")

    @staticmethod
    def empty() -> "Attachments":
        return Attachments(np.zeros((0, 4), np.int32), np.zeros((0, 4)), np.zeros(0))

    @staticmethod
    def at_vertices(vertex_ids, stiffness) -> "Attachments":
        """One attachment per vertex (weight 1 on the vertex)."""
        ids = np.asarray(vertex_ids, dtype=np.int32).reshape(-1)
        weights = np.zeros((len(ids), 4))
        weights[:, 0] = 1.0
        return Attachments(np.repeat(ids[:, None], 4, axis=1), weights,
                           np.broadcast_to(np.asarray(stiffness, float), ids.shape).copy())

    @staticmethod
    def at_points(mesh: TetMesh | ShellMesh, points, stiffness) -> "Attachments":
        """One attachment per point, by barycentric weights in the element containing it.

        A point outside the mesh attaches to the element whose barycentric coordinates it
        violates least (weights are clamped to [0, 1] and renormalised).

        On a :class:`~wcut.mesh.ShellMesh` a point is projected onto the plane of each flat
        corner triangle (rest configuration), its barycentric coordinates there are clamped
        and renormalised, and it attaches to the triangle whose clamped point is nearest
        (three weights on the corners; the fourth slot repeats the first corner with weight 0).
        """
        points = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if points.shape[1] != 3 or not np.isfinite(points).all():
            raise ModelError(f"attachment points must be finite (S, 3) coordinates, got shape {points.shape}")
        springs = np.broadcast_to(np.asarray(stiffness, float), (len(points),)).copy()
        if isinstance(mesh, ShellMesh):
            corners = mesh.triangles[:, :3]
            A = mesh.vertices[corners[:, 0]]  # (T, 3)
            e1, e2 = mesh.vertices[corners[:, 1]] - A, mesh.vertices[corners[:, 2]] - A
            d = points[:, None, :] - A[None]  # (S, T, 3)
            g11, g12, g22 = (np.einsum("ti,ti->t", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
            r1, r2 = np.einsum("sti,ti->st", d, e1), np.einsum("sti,ti->st", d, e2)
            det = g11 * g22 - g12 * g12  # positive: ShellMesh has no degenerate corner triangle
            b1, b2 = (g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det  # of the projected point
            w = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=-1), 0.0, 1.0)  # (S, T, 3)
            w /= w.sum(axis=-1, keepdims=True)  # at least one coordinate is positive: they sum to 1
            clamped = A + w[..., 1:2] * e1 + w[..., 2:3] * e2
            t = np.argmin(np.linalg.norm(points[:, None, :] - clamped, axis=-1), axis=1)  # (S,)
            s = np.arange(len(points))
            indices = corners[t][:, [0, 1, 2, 0]].astype(np.int32)
            weights = np.concatenate([w[s, t], np.zeros((len(points), 1))], axis=1)
            return Attachments(indices, weights, springs)
        corners = mesh.tets[:, :4]  # a quadratic element: its corners' linear interpolation
        X3 = mesh.vertices[corners[:, 3]]
        Dm_inv = np.linalg.inv(edge_matrices(mesh.vertices, corners))
        indices = np.empty((len(points), 4), np.int32)
        weights = np.empty((len(points), 4))
        for s, p in enumerate(points):
            xi = np.einsum("mij,mj->mi", Dm_inv, p - X3)
            bary = np.concatenate([xi, 1.0 - xi.sum(axis=1, keepdims=True)], axis=1)
            e = int(np.argmax(bary.min(axis=1)))
            w = np.clip(bary[e], 0.0, 1.0)
            indices[s], weights[s] = corners[e], w / w.sum()
        return Attachments(indices, weights, springs)

    def __len__(self) -> int:
        return len(self.stiffness)

    def concatenate(self, other: "Attachments") -> "Attachments":
        return Attachments(np.concatenate([self.indices, other.indices]), np.concatenate([self.weights, other.weights]),
                           np.concatenate([self.stiffness, other.stiffness]))


def _rest_frames(rest: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Dm^{-1}`` (M, 3, 3) and rest volumes (M,) of elements (rest positions in metres)."""
    X = rest[tets]
    c0, c1, c2 = X[:, 0] - X[:, 3], X[:, 1] - X[:, 3], X[:, 2] - X[:, 3]  # Dm's columns (edge_matrices)
    # Closed form: the rows of Dm^{-1} are cross products of Dm's columns over det Dm (a tenth
    # of np.linalg.inv's time on the few hundred elements of a cut; elements are well shaped).
    rows = np.empty((len(X), 3, 3))
    for i, (a, b) in enumerate(((c1, c2), (c2, c0), (c0, c1))):
        rows[:, i, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
        rows[:, i, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
        rows[:, i, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    det = c0[:, 0] * rows[:, 0, 0] + c0[:, 1] * rows[:, 0, 1] + c0[:, 2] * rows[:, 0, 2]
    return rows / det[:, None, None], np.abs(det) / 6.0


def _quadratic_rest_frames(rest: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J^{-1}`` (M, 4, 3, 3) at the Gauss points of quadratic elements (M, 10) and the
    points' volume shares ``w_g det J`` (M, 4) in m^3 (rest positions in metres)."""
    J = p2.jacobians(rest, tets, p2.GAUSS_POINTS)
    return np.linalg.inv(J), np.linalg.det(J) * p2.GAUSS_WEIGHTS


def _untouched_vertices(change) -> np.ndarray:
    """Vertices after a change that are vertices of before, unmoved (weight 1 on themselves)."""
    new_or_moved = np.zeros(change.vertex_count_after, dtype=bool)
    new_or_moved[change.new_vertices] = True
    new_or_moved[change.moved_vertices[change.moved_vertices < change.vertex_count_after]] = True
    return np.flatnonzero(~new_or_moved & (change.vertex_weights[:, 0] == 1.0))


# A change is local: most elements and vertices keep their index, and all that is attached to
# it. Model.rebuild keeps the rows of each array and recomputes only those that may differ
# (rest frames bit for bit as recomputing every row gives them; masses updated by the shares of
# the elements that changed, in float64). On the CPU each array is the start of a
# numpy buffer with spare rows, so a rebuild can also write them in place.

def _spare_rows(count: int) -> int:
    """Rows a CPU buffer holds beyond ``count`` so that the next cuts (which add elements and
    vertices) can rebuild in place: an eighth more, and at least 256."""
    return count // 8 + 256


def _spare_buffer(old: np.ndarray, count: int, dtype) -> np.ndarray:
    """A new buffer of ``count`` rows and spare ones, of ``dtype``, its first rows ``old``'s
    (as many as it has, up to ``count``)."""
    buf = np.empty((count + _spare_rows(count),) + old.shape[1:], dtype=dtype)
    k = min(len(old), count)
    buf[:k] = old[:k]
    return buf


class _Rows:
    """The host arrays a rebuild writes: each the first rows of a buffer (kept in
    ``buffers``), the old object's own when ``in_place`` and it has room (its first rows then
    are the old rows already), else a new one with spare rows after the old rows copied."""

    def __init__(self, old_buffers: dict | None = None):
        self.old_buffers = old_buffers or {}
        self.buffers: dict[str, np.ndarray] = {}

    def __call__(self, name: str, old: np.ndarray, count: int) -> np.ndarray:
        buf = self.old_buffers.get(name)
        if buf is None or len(buf) < count:
            buf = _spare_buffer(old, count, old.dtype)
        self.buffers[name] = buf
        return buf[:count]

    def take(self, name: str, old: np.ndarray, reparented: "_Reparented") -> np.ndarray:
        """``old[parent]`` for the element parents after a change, given the rows where the
        parent is not the element of the same index (the values are gathered before any is
        written: ``old`` may be the buffer written)."""
        out = self(name, old, reparented.count)
        out[reparented.rows] = old[reparented.parents]
        return out


@dataclass(frozen=True)
class _Reparented:
    """The elements after a change (``count``) whose parent is not the element of the same
    index before (``rows``, ascending), and those parents."""

    count: int
    rows: np.ndarray
    parents: np.ndarray


#: a model's per-element material arrays
_MATERIAL = ("tet_density", "tet_youngs_modulus", "tet_poisson_ratio")


def _reparented(change) -> np.ndarray:
    """Elements after a change whose parent is not the element of the same index before:
    the added or renumbered ones and those past the old end (the change's own list when it
    has one: a scan of every element otherwise)."""
    if change.reparented_elements is not None:
        return change.reparented_elements
    parent = change.element_parent
    k = min(change.element_count_before, len(parent))
    return np.concatenate([np.flatnonzero(parent[:k] != np.arange(k)), np.arange(k, len(parent))])


def _reparented_rows(change) -> _Reparented:
    """:func:`_reparented` with the parents of those elements."""
    rows = _reparented(change)
    return _Reparented(change.element_count_after, rows, change.element_parents(rows))


def _touched_vertices(change) -> np.ndarray:
    """Vertices after a change that are not simply the vertex of the same index before:
    created, moved, renumbered, or interpolated from others. Sorted (the change's own list
    when it has one: a scan of every vertex otherwise)."""
    if change.touched_vertices is not None:
        return change.touched_vertices
    sources, weights = change.vertex_sources, change.vertex_weights
    itself = (sources[:, 0] == np.arange(len(sources))) & (weights[:, 0] == 1.0)
    for k in range(1, weights.shape[1]):  # column by column: far faster than .all(axis=1) on (N, K)
        itself &= weights[:, k] == 0.0
    moved = change.moved_vertices[change.moved_vertices < change.vertex_count_after]
    return np.union1d(np.flatnonzero(~itself), np.concatenate([change.new_vertices, moved]))


def _interpolated(out: np.ndarray, old: np.ndarray, change, touched: np.ndarray) -> np.ndarray:
    """Vertex attribute ``old`` (N_A, 3) after ``change`` into ``out`` (N_B rows, the first
    ones ``old``'s): the weighted sum of its sources, computed where it may differ from
    ``old`` (``touched``) and rounded to ``out``'s type."""
    sources, weights = change.vertex_rows(touched)
    out[touched] = np.einsum("vk,vkj->vj", weights, old[sources])
    return out


def _forces_after(out: np.ndarray, old: np.ndarray, change, touched: np.ndarray) -> np.ndarray:
    """External forces after ``change`` into ``out`` (N_B rows, the first ones ``old``'s), from
    those before (``old``, (N_A, 3)): kept on the vertices of before that did not move, zero
    on the others (``touched`` holds every vertex that is not simply the vertex of the same
    index before)."""
    new_or_moved = np.isin(touched, change.new_vertices) | np.isin(touched, change.moved_vertices)
    sources, weights = change.vertex_rows(touched)
    kept_rows = ~new_or_moved & (weights[:, 0] == 1.0)  # e.g. renumbered
    kept = touched[kept_rows]
    kept_forces = old[sources[kept_rows, 0]]
    out[touched] = 0.0
    out[kept] = kept_forces
    return out


def _device_array(host, dtype, device, buffers: dict | None = None, name: str = ""):
    """A device array of host data (converted to ``dtype``'s scalar type).

    On the CPU it wraps the start of a numpy buffer with spare rows, kept in
    ``buffers[name]`` (for :meth:`Model.rebuild` in place); host data that already is the
    start of that buffer (a rebuild's) is wrapped as it is, not copied."""
    if not wp.get_device(device).is_cpu:
        return wp.array(host, dtype=dtype, device=device)
    scalar = getattr(dtype, "_wp_scalar_type_", dtype)
    scalar = np.dtype(np.float32 if scalar is float else wp.dtype_to_numpy(scalar))
    buffers = {} if buffers is None else buffers
    buf = buffers.get(name)
    if buf is None or getattr(host, "base", None) is not buf or buf.dtype != scalar:
        host = np.asarray(host)
        buf = buffers[name] = _spare_buffer(host, len(host), scalar)
    return wp.array(buf[: len(host)], dtype=dtype, device=device, copy=False)


def _is_shell(mesh) -> bool:
    return isinstance(mesh, ShellMesh)


class State:
    """Time-varying data of a model (Newton's names).

    Attributes:
        particle_q: (N,) wp.vec3 positions (m).
        particle_qd: (N,) wp.vec3 velocities (m/s).
        particle_f: (N,) wp.vec3 external nodal forces (N) applied during a step from this
            state; zero by default. The solver reads it and never clears it.
        tet_rotation: wp.quat rotations of the last step (warm start): (M,) one per linear
            element, (M, 4) one per Gauss point of a quadratic element.
    """

    def __init__(self, model: "Model"):
        d = model.device
        self._buffers: dict[str, np.ndarray] = {}
        if not d.is_cpu:
            self.particle_q = wp.clone(model.particle_q)
            self.particle_qd = wp.clone(model.particle_qd)
            self.particle_f = wp.zeros(model.particle_count, dtype=wp.vec3, device=d)
            self.tet_rotation = wp.full(model.tet_rotation_shape, wp.quat_identity(), dtype=wp.quat, device=d)
            return
        shape = (model.tet_rotation_shape,) if np.isscalar(model.tet_rotation_shape) else model.tet_rotation_shape
        identity = np.zeros(tuple(shape) + (4,), dtype=np.float32)
        identity[..., 3] = 1.0
        for name, host, dtype in (("particle_q", model.particle_q.numpy(), wp.vec3),
                                  ("particle_qd", model.particle_qd.numpy(), wp.vec3),
                                  ("particle_f", np.zeros((model.particle_count, 3), dtype=np.float32), wp.vec3),
                                  ("tet_rotation", identity, wp.quat)):
            setattr(self, name, _device_array(host, dtype, d, self._buffers, name))

    @classmethod
    def of(cls, model: "Model", particle_q: np.ndarray, particle_qd: np.ndarray, particle_f: np.ndarray,
           tet_rotation: np.ndarray, buffers: dict | None = None) -> "State":
        """A State of ``model`` holding these host arrays ((N, 3), (N, 3), (N, 3), (M, 4)),
        uploaded once (no initial values to overwrite); on the CPU those that are the start of
        ``buffers[name]`` (a rebuild's) are wrapped, not copied."""
        state = cls.__new__(cls)
        d = model.device
        state._buffers = {} if buffers is None or not d.is_cpu else buffers
        for name, host, dtype in (("particle_q", particle_q, wp.vec3), ("particle_qd", particle_qd, wp.vec3),
                                  ("particle_f", particle_f, wp.vec3), ("tet_rotation", tet_rotation, wp.quat)):
            setattr(state, name, _device_array(host, dtype, d, state._buffers, name))
        return state

    def clear_forces(self) -> None:
        """Set the external forces to zero."""
        self.particle_f.zero_()


class Control:
    """User inputs of a step besides forces.

    Attributes:
        attachment_target: (S,) wp.vec3 targets of the model's attachments (m), initially the
            rest positions of the attached points (so they start relaxed).
    """

    def __init__(self, model: "Model"):
        self.attachment_target = wp.array(model.attachment_rest_points.numpy(), dtype=wp.vec3, device=model.device)


class Model:
    """Rest data of a corotational tetrahedral object: linear (P1) or quadratic (P2) elements.

    Args:
        mesh: the validated mesh (rest configuration, metres): a :class:`wcut.mesh.TetMesh`
            (4-node elements) or a :class:`wcut.quadratic.QuadraticTetMesh` (10-node elements,
            possibly curved).
        density: kg/m^3, a number or one value per element.
        youngs_modulus: Pa, a number or one value per element.
        poisson_ratio: dimensionless in (-1, 0.5), a number or one value per element.
        rayleigh_mass: Rayleigh damping coefficient alpha of ``D = alpha M + beta K`` (1/s).
        rayleigh_stiffness: Rayleigh damping coefficient beta (s).
        gravity: acceleration (m/s^2).
        fixed: vertices held in place (Dirichlet): integer indices or a boolean mask.
        attachments: attachment springs (targets in :class:`Control`). On quadratic elements
            they weigh the element's corners (a linear interpolation of the attached point).
        thickness: shell thickness (m), one number or one per triangle; shells only.
        device: Warp device; defaults to Warp's current device.

    A :class:`wcut.mesh.ShellMesh` gives a model with triangles and hinges and no tetrahedra
    (``tet_count == 0``): the plane-stress membrane of ``wcut.kernels.tri_p2`` and the hinge
    bending of ``wcut.kernels.bending``, with the same solver, constraints and attachments.

    Attributes (every array is a ``wp.array`` on ``device``):
        tet_order: 1 or 2, the elements' polynomial degree.
        particle_q, particle_qd: (N,) vec3 rest positions (m) and initial velocities (m/s).
        particle_mass: (N,) lumped mass (kg). P1: each element gives a quarter of its mass to
            each vertex (the row-sum lumping of thesis 3.2). P2: HRZ lumping (Hinton, Rock and
            Zienkiewicz 1976), each node's share proportional to its diagonal entry of the
            consistent mass matrix: 1/36 of the element mass per corner, 4/27 per edge node.
            Row-sum lumping would give the corners a negative mass (-1/20); HRZ keeps every
            mass positive, the total exact and the mass diagonal, so the solver's
            Jacobi-preconditioned conjugate gradient and node-wise kernels serve P2 unchanged.
        particle_load_mass: (N,) ``int rho N_a dV`` (kg): gravity acts on node a as
            ``particle_load_mass[a] * g``, the consistent load vector. Equal to
            ``particle_mass`` for P1; for P2 the corners' entries are negative (-1/20 of the
            element mass), which keeps the static response of P2 of order 2 (a lumped load
            would perturb it).
        particle_fixed: (N,) int32, 1 for a fixed vertex.
        tet_indices: (M,) vertex indices, positively oriented: vec4i (P1) or a length-10
            int32 vector in VTK tetra10 order (P2; type ``wcut.kernels.tet_p2.vec10i``).
        tet_poses: P1: (M,) mat33 ``Dm^{-1}`` (Newton's name), ``Dm = [X0-X3 | X1-X3 | X2-X3]``;
            row l is the shape-function gradient grad N_l (1/m), l = 0..2. P2: (M, 4) mat33,
            ``J^{-1}`` at each Gauss point (see ``wcut.kernels.tet_p2``).
        tet_rest_volume: (M,) rest volume (m^3); exact for curved P2 elements.
        tet_stiffness: P1: (M,) vec2 ``(V mu, V lambda)`` (N*m). P2: (M, 4) vec2, the same
            with ``V`` the Gauss point's volume share ``w det J``.
        tet_density, tet_youngs_modulus, tet_poisson_ratio: (M,) material (kg/m^3, Pa, 1).
        attachment_indices, attachment_weights, attachment_stiffness: (S,) vec4i, vec4, float (N/m).
        attachment_rest_points: (S,) vec3 rest positions of the attached points (m).
        tri_count, edge_count: numbers of shell triangles and bending hinges (0 for a solid).
        tri_indices: (T,) 6-node triangles (VTK triangle6 order; ``wcut.kernels.tri_p2.vec6i``).
        tri_poses: (T, 3) mat22 ``J^{-1}`` at the Gauss points (1/m), see ``wcut.kernels.tri_p2``.
        tri_stiffness: (T, 3) vec2 ``A_g h (mu, lambda*)`` (N*m): Gauss area share times
            thickness times the plane-stress Lame parameters.
        tri_lame: (T,) vec2 ``(mu, lambda*)`` (Pa); tri_rest_area: (T,) m^2; tri_thickness: (T,) m.
        tri_density, tri_youngs_modulus, tri_poisson_ratio: (T,) material (kg/m^3, Pa, 1).
        particle_mass of a shell: HRZ lumping of the 6-node triangle (3/57 of ``rho h A`` per
            corner, 16/57 per edge node); its consistent load puts gravity on the edge nodes
            only (1/3 each; a corner's shape function integrates to zero).
        edge_indices, edge_weights, edge_stiffness, edge_rest_curvature: (H,) the bending
            hinges of ``wcut.shell.hinges`` (vec4i, vec4 1/m, float N*m, vec3).

    Rest frames are computed from the float32-rounded rest positions the kernels see, so the
    rest state is exactly stress-free in float32.
    """

    def __init__(self, mesh: TetMesh, *, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3,
                 rayleigh_mass: float = 0.0, rayleigh_stiffness: float = 0.0, gravity=(0.0, 0.0, -9.81),
                 fixed=None, attachments: Attachments | None = None, thickness=1.0e-3, device=None):
        self.device = wp.get_device(device)
        is_shell = _is_shell(mesh)
        M, N = (mesh.triangle_count if is_shell else mesh.tet_count), mesh.vertex_count

        rho = _per_element(density, M, "density", 0.0, np.inf)
        E = _per_element(youngs_modulus, M, "youngs_modulus", 0.0, np.inf)
        nu = _per_element(poisson_ratio, M, "poisson_ratio", -1.0, 0.5)
        for name, value in (("rayleigh_mass", rayleigh_mass), ("rayleigh_stiffness", rayleigh_stiffness)):
            value = _number(value, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ModelError(f"{name}: expected a finite value >= 0, got {value}")
        self.rayleigh_mass = float(rayleigh_mass)
        self.rayleigh_stiffness = float(rayleigh_stiffness)
        try:
            gravity = np.asarray(gravity, dtype=np.float64)
        except (TypeError, ValueError):
            raise ModelError(f"gravity: expected three numbers, got {gravity!r}") from None
        if gravity.shape != (3,) or not np.isfinite(gravity).all():
            raise ModelError(f"gravity: expected three finite components, got {gravity.tolist()}")
        if np.abs(gravity).max() > MAX_GRAVITY:
            raise ModelError(f"gravity: {gravity.tolist()} m/s^2 is beyond any load a simulation takes "
                             f"(at most {MAX_GRAVITY:g} m/s^2 along each axis)")
        self.gravity = wp.vec3(*gravity)

        fixed_mask = np.zeros(N, dtype=np.int32)
        fixed_mask[_vertex_indices([] if fixed is None else fixed, N, "fixed")] = 1
        attachments = attachments if attachments is not None else Attachments.empty()
        outside = attachments.indices[(attachments.indices < 0) | (attachments.indices >= N)]
        if len(outside):
            raise ModelError(f"attachments: vertex index {outside[0]} out of range 0..{N - 1}")

        rest = mesh.vertices.astype(np.float32).astype(np.float64)  # what the kernels see
        if is_shell:
            h = _per_element(thickness, M, "thickness", 0.0, np.inf)
            self._upload_shell(mesh, rest, rho, E, nu, h, fixed_mask, attachments)
            return
        frames = _quadratic_rest_frames if getattr(mesh, "order", 1) == 2 else _rest_frames
        poses, volume = frames(rest, mesh.tets)
        self._upload(mesh, rest, poses, volume, rho, E, nu, fixed_mask, attachments)

    def _upload(self, mesh: TetMesh, rest, poses, volume, rho, E, nu, fixed_mask, attachments: Attachments) -> None:
        """Derive masses and stiffness from the host data and create the device arrays.

        ``poses`` and ``volume`` are the rest frames: ``Dm^{-1}`` (M, 3, 3) and volumes (M,)
        for P1, ``J^{-1}`` (M, 4, 3, 3) and Gauss volume shares (M, 4) for P2. A shell mesh
        gets empty tetrahedral arrays."""
        tets = np.zeros((0, 4), dtype=np.int64) if _is_shell(mesh) else mesh.tets
        N, M = len(rest), len(tets)
        mu, lam = lame_parameters(E, nu)
        if getattr(mesh, "order", 1) == 1:
            mass = np.bincount(tets.ravel(), weights=np.repeat(rho * volume / 4.0, 4), minlength=N)
            load_mass = mass
            stiffness = np.stack([volume * mu, volume * lam], axis=-1)
            rest_volume = volume
        else:
            rest_volume = p2.volumes(rest, tets)
            mass = np.bincount(tets.ravel(), weights=(np.outer(rho * rest_volume, p2.HRZ_FRACTIONS)).ravel(),
                               minlength=N)
            load = volume @ p2.shape_functions(p2.GAUSS_POINTS)  # (M, 10): int N_a dV by the Gauss rule
            load_mass = np.bincount(tets.ravel(), weights=(rho[:, None] * load).ravel(), minlength=N)
            stiffness = volume[:, :, None] * np.stack([mu, lam], axis=-1)[:, None, :]
        self._set_arrays(mesh, rest, tets, mass, load_mass, poses, rest_volume, stiffness, fixed_mask,
                         (rho, E, nu), attachments)
        if getattr(mesh, "order", 1) == 1:  # float64, unrounded: what a rebuild updates the masses from
            rows = _Rows()
            self._mass_sums, self._volumes = rows("mass_sums", mass, N), rows("volumes", volume, M)
            self._buffers.update(rows.buffers)  # host-only: a rebuild in place writes them

    def _set_arrays(self, mesh, rest, tets, mass, load_mass, poses, rest_volume, stiffness, fixed_mask, material,
                    attachments: Attachments, buffers: dict | None = None) -> None:
        """Create the device arrays of the model of ``mesh`` from host arrays, the derived ones
        included (``tets`` its elements, none for a shell; ``material``: density, Young's
        modulus and Poisson's ratio per element). On the CPU the arrays wrap numpy buffers with
        spare rows (``_buffers``); host arrays that already are the start of ``buffers[name]``
        (a rebuild's) are wrapped as they are."""
        N, M = len(rest), len(tets)
        self.mesh = mesh
        self.tet_order = getattr(mesh, "order", 1)
        self.particle_count, self.tet_count = N, M
        if self.tet_order == 1:
            self.tet_rotation_shape, index_type = M, wp.vec4i
        else:
            from .kernels.tet_p2 import vec10i

            self.tet_rotation_shape, index_type = (M, 4), vec10i
        rest_points = np.einsum("sj,sjk->sk", attachments.weights, rest[attachments.indices]) \
            if len(attachments) else np.zeros((0, 3))
        d = self.device
        self._buffers = {} if buffers is None or not d.is_cpu else buffers
        self.attachment_count = len(attachments)
        self.particle_qd = wp.zeros(N, dtype=wp.vec3, device=d)
        for name, host, dtype in (
                ("particle_q", rest, wp.vec3), ("particle_mass", mass, float), ("particle_load_mass", load_mass, float),
                ("particle_fixed", fixed_mask, wp.int32), ("tet_indices", tets, index_type),
                ("tet_poses", poses, wp.mat33), ("tet_rest_volume", rest_volume, float),
                ("tet_stiffness", stiffness, wp.vec2), ("tet_density", material[0], float),
                ("tet_youngs_modulus", material[1], float), ("tet_poisson_ratio", material[2], float),
                ("attachment_indices", attachments.indices.reshape(-1, 4), wp.vec4i),
                ("attachment_weights", attachments.weights.reshape(-1, 4), wp.vec4),
                ("attachment_stiffness", attachments.stiffness, float),
                ("attachment_rest_points", rest_points, wp.vec3)):
            setattr(self, name, _device_array(host, dtype, d, self._buffers, name))
        self.tri_count = self.edge_count = 0

    def _upload_shell(self, mesh, rest, rho, E, nu, thickness, fixed_mask, attachments: Attachments) -> None:
        """The device arrays of a thin shell (``mesh`` a ShellMesh): no tetrahedra."""
        from .kernels.tri_p2 import vec6i

        poses, areas, _ = shell.rest_frames(rest, mesh.triangles)
        if not (areas > 0.0).all():
            e = int(np.argwhere(areas <= 0.0)[0, 0])
            raise ModelError(f"triangle {e} is folded: non-positive Jacobian at a Gauss point")
        N, T = len(rest), len(mesh.triangles)
        tris = mesh.triangles
        mu, lam = shell.plane_stress_lame(E, nu)
        rest_area = areas.sum(axis=1)
        mass = np.bincount(tris.ravel(), weights=np.outer(rho * thickness * rest_area, shell.HRZ_FRACTIONS).ravel(),
                           minlength=N)
        load = np.bincount(tris.ravel(), weights=np.outer(rho * thickness * rest_area, shell.LOAD_FRACTIONS).ravel(),
                           minlength=N)
        hinge_indices, hinge_weights, hinge_stiffness, hinge_rest = shell.hinges(
            rest, tris, shell.flexural_rigidity(E, nu, thickness))
        # the tetrahedral attributes exist, empty, so a solid's code paths see no elements
        self._upload(mesh, rest, np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0),
                     fixed_mask, attachments)
        d = self.device
        self.particle_mass = wp.array(mass, dtype=float, device=d)
        self.particle_load_mass = wp.array(load, dtype=float, device=d)
        self.tri_count, self.edge_count = T, len(hinge_indices)
        self.tri_indices = wp.array(tris.astype(np.int32), dtype=vec6i, device=d)
        self.tri_poses = wp.array(poses, dtype=wp.mat22, device=d)
        self.tri_stiffness = wp.array((areas * thickness[:, None])[:, :, None] * np.stack([mu, lam], axis=-1)[:, None],
                                      dtype=wp.vec2, device=d)
        self.tri_lame = wp.array(np.stack([mu, lam], axis=-1), dtype=wp.vec2, device=d)
        self.tri_rest_area = wp.array(rest_area, dtype=float, device=d)
        self.tri_thickness = wp.array(thickness, dtype=float, device=d)
        self.tri_density = wp.array(rho, dtype=float, device=d)
        self.tri_youngs_modulus = wp.array(E, dtype=float, device=d)
        self.tri_poisson_ratio = wp.array(nu, dtype=float, device=d)
        self.edge_indices = wp.array(hinge_indices.astype(np.int32), dtype=wp.vec4i, device=d)
        self.edge_weights = wp.array(hinge_weights, dtype=wp.vec4, device=d)
        self.edge_stiffness = wp.array(hinge_stiffness, dtype=float, device=d)
        self.edge_rest_curvature = wp.array(hinge_rest, dtype=wp.vec3, device=d)

    def rebuild(self, mesh: TetMesh, change, state: State | None = None, *,
                in_place: bool = False) -> tuple["Model", State | None]:
        """The model of ``mesh``, derived from this one by ``change`` (a
        :class:`wcut.topology.TopologyChange`), and ``state`` carried over.

        Only elements whose rest shape changed get new rest frames; the others keep theirs, and
        every element takes the material of its parent element. A vertex is fixed when all the
        vertices it is interpolated from are. Attachments follow their vertices. The state's
        positions and velocities are interpolated with the change's weights (exact for linear
        elements, and for quadratic ones cut by :class:`wcut.cut.QuadraticCutter`, whose
        weights are the shape functions), external forces stay on surviving vertices,
        rotations are inherited from the parent element (the warm start of the polar
        decomposition; per Gauss point for quadratic elements).

        A shell (a crack opened by :mod:`wcut.topology.shell`) is laid out anew from ``mesh``,
        each triangle with its parent's material and thickness; its state is carried the same way.

        ``in_place``: on the CPU, for linear elements, write the rows that change into this
        model's and this state's own buffers where they have room (each array keeps spare rows
        for the elements and vertices cuts add), instead of copying every array: what a
        simulation that cuts wants (the cost then follows the cut, not the mesh). This model
        and ``state`` must not be used afterwards. The result is the same either way.

        Returns ``(model, state)``; the solver must be made again for the new model.
        """
        if self.tri_count or _is_shell(mesh):
            return self._rebuild_shell(mesh, change, state)
        if getattr(mesh, "order", 1) != self.tet_order:
            raise ModelError(f"rebuild: a mesh of order {getattr(mesh, 'order', 1)} for a model of order "
                             f"{self.tet_order}")
        if change.vertex_count_before != self.particle_count or change.element_count_before != self.tet_count:
            raise ModelError(f"rebuild: the change is from a mesh of {change.vertex_count_before} vertices and "
                             f"{change.element_count_before} elements, the model has {self.particle_count} "
                             f"and {self.tet_count}")
        if change.vertex_count_after != mesh.vertex_count or change.element_count_after != mesh.tet_count:
            raise ModelError("rebuild: the change does not lead to this mesh")
        reparented, touched = _reparented_rows(change), _touched_vertices(change)
        in_place = in_place and self.device.is_cpu and self.tet_order == 1
        rows = _Rows(self._buffers if in_place else None)
        rest = mesh.vertices.astype(np.float32).astype(np.float64)
        fixed_mask, attachments = self._fixed_after(change, touched, rows), self._attachments_after(change)
        model = Model.__new__(Model)
        model.device = self.device
        model.rayleigh_mass, model.rayleigh_stiffness, model.gravity = \
            self.rayleigh_mass, self.rayleigh_stiffness, self.gravity
        if self.tet_order == 2:  # the Gauss points' volume shares are not kept: all anew (cheap)
            material = [rows.take(name, getattr(self, name).numpy(), reparented) for name in _MATERIAL]
            poses, volume = _quadratic_rest_frames(rest, mesh.tets)
            model._upload(mesh, rest, poses, volume, *(a.astype(np.float64) for a in material), fixed_mask,
                          attachments)
        else:
            tets, mass, load_mass, poses, volume, stiffness, material, sums, volumes = self._linear_rest_after(
                mesh, rest, change, reparented, touched, rows)
            rest32 = rows("particle_q", self.particle_q.numpy(), len(rest))
            rest32[:] = rest
            model._set_arrays(mesh, rest32, tets, mass, load_mass, poses, volume, stiffness, fixed_mask, material,
                              attachments, rows.buffers)
            model._mass_sums, model._volumes = sums, volumes
        if state is None:
            return model, None
        rows = _Rows(getattr(state, "_buffers", None) if in_place else None)
        count = mesh.vertex_count
        q, qd, f = (a.numpy() for a in (state.particle_q, state.particle_qd, state.particle_f))
        return model, State.of(model, _interpolated(rows("particle_q", q, count), q, change, touched),
                               _interpolated(rows("particle_qd", qd, count), qd, change, touched),
                               _forces_after(rows("particle_f", f, count), f, change, touched),
                               rows.take("tet_rotation", state.tet_rotation.numpy(), reparented), rows.buffers)

    def _linear_rest_after(self, mesh, rest, change, reparented, touched, rows: _Rows):
        """Element indices (M, 4) int32, masses and load masses (N,), ``Dm^{-1}`` (M, 3, 3),
        volumes (M,), stiffness (M, 2) and material (density, Young's modulus, Poisson's ratio,
        (M,) each) of the linear model of ``mesh`` after ``change`` (float32, as uploaded,
        written by ``rows``; ``rest`` the float32-rounded rest positions), then the float64
        mass sums (N,) and unrounded volumes (M,) they derive from.

        An element keeps the rows of its parent unless its rest shape changed; only those are
        computed. A vertex's mass changes by the shares of the elements that changed around it
        (in shape, parent or vertices): those of before are taken off, those of after added, in
        float64 from the unrounded sums and volumes (from the float32 masses, a vertex left
        with a sliver's mass would keep the rounding error of its old mass); a new vertex's
        mass is the sum of its elements' shares. (After vertices were dropped and the others
        renumbered, every mass is summed anew.)"""
        changed = change.rest_changed_elements()
        tets, old_tets = mesh.tets, self.tet_indices.numpy()
        N, M, M_before, N_before = mesh.vertex_count, len(tets), len(old_tets), self.particle_count
        k = min(M, M_before)
        if change.rewired_elements is None:  # every element row compared
            differ = np.flatnonzero((old_tets[:k] != tets[:k]).view(np.int32) != 0)  # 4 bools as one int32
        else:  # the rows that may differ besides the reparented and reshaped ones
            rewired = change.rewired_elements
            differ = rewired[(old_tets[rewired] != tets[rewired]).any(axis=1)]
        renewed = np.union1d(differ, np.concatenate([reparented.rows, changed]))
        # the shares of before, read before any row is overwritten
        gone = np.concatenate([renewed[renewed < M_before], np.arange(M, M_before)])
        old_shares = self.tet_density.numpy()[gone].astype(np.float64) * self._volumes[gone] / 4.0
        old_vertices = old_tets[gone].astype(np.int64)

        indices = rows("tet_indices", old_tets, M)
        indices[renewed] = tets[renewed]
        material = [rows.take(name, getattr(self, name).numpy(), reparented) for name in _MATERIAL]
        poses = rows.take("tet_poses", self.tet_poses.numpy(), reparented)
        volume = rows.take("tet_rest_volume", self.tet_rest_volume.numpy(), reparented)
        stiffness = rows.take("tet_stiffness", self.tet_stiffness.numpy(), reparented)
        volumes = rows.take("volumes", self._volumes, reparented)
        new_poses, new_volume = _rest_frames(rest, tets[changed])
        poses[changed], volume[changed], volumes[changed] = new_poses, new_volume, new_volume
        mu, lam = lame_parameters(material[1][changed], material[2][changed])
        stiffness[changed] = np.stack([new_volume * mu, new_volume * lam], axis=-1)

        mass = rows("particle_mass", self.particle_mass.numpy(), N)
        load_mass = rows("particle_load_mass", self.particle_load_mass.numpy(), N)
        sums = rows("mass_sums", self._mass_sums, N)
        kept = touched[touched < N_before]
        if np.any(change.vertex_rows(kept)[0][:, 0] != kept):  # old and new vertex numbers differ: sum every mass anew
            elements, start = np.arange(M), np.zeros(N)
        else:
            elements, start = renewed, np.zeros(N)
            start[:N_before] = sums[:N_before]
            start[:N_before] -= np.bincount(old_vertices.ravel(), weights=np.repeat(old_shares, 4), minlength=N_before)
        shares = material[0][elements].astype(np.float64) * volumes[elements] / 4.0  # unrounded, as Model sums them
        total = start + np.bincount(tets[elements].ravel(), weights=np.repeat(shares, 4), minlength=N)
        moved = np.zeros(N, dtype=bool)
        moved[tets[elements].ravel()] = True
        moved[old_vertices[old_vertices < N].ravel()] = True
        moved[N_before:] = True
        sums[moved] = mass[moved] = load_mass[moved] = total[moved]
        return indices, mass, load_mass, poses, volume, stiffness, material, sums, volumes

    def _rebuild_shell(self, mesh, change, state: State | None) -> tuple["Model", State | None]:
        """:meth:`rebuild` of a shell: every triangle takes its parent's material and thickness,
        and the rest data (frames, masses, hinges) are laid out anew from ``mesh``: a crack
        changes the hinges around it, and a sheet is small enough to redo them all."""
        if not (self.tri_count and _is_shell(mesh)):
            raise ModelError("rebuild: a shell model is rebuilt from a ShellMesh, and a solid from a solid mesh")
        if change.vertex_count_before != self.particle_count or change.element_count_before != self.tri_count:
            raise ModelError(f"rebuild: the change is from a mesh of {change.vertex_count_before} vertices and "
                             f"{change.element_count_before} triangles, the model has {self.particle_count} "
                             f"and {self.tri_count}")
        if change.vertex_count_after != mesh.vertex_count or change.element_count_after != mesh.triangle_count:
            raise ModelError("rebuild: the change does not lead to this mesh")
        parent, touched = change.element_parent, _touched_vertices(change)
        rho, E, nu, h = (a.numpy().astype(np.float64)[parent] for a in (
            self.tri_density, self.tri_youngs_modulus, self.tri_poisson_ratio, self.tri_thickness))
        model = Model(mesh, density=rho, youngs_modulus=E, poisson_ratio=nu, thickness=h,
                      rayleigh_mass=self.rayleigh_mass, rayleigh_stiffness=self.rayleigh_stiffness,
                      gravity=tuple(self.gravity), fixed=self._fixed_after(change, touched) == 1,
                      attachments=self._attachments_after(change), device=self.device)
        if state is None:
            return model, None
        rows, count = _Rows(), mesh.vertex_count
        q, qd, f = (a.numpy() for a in (state.particle_q, state.particle_qd, state.particle_f))
        return model, State.of(model, _interpolated(rows("particle_q", q, count), q, change, touched),
                               _interpolated(rows("particle_qd", qd, count), qd, change, touched),
                               _forces_after(rows("particle_f", f, count), f, change, touched), np.zeros((0, 4)),
                               rows.buffers)

    def _fixed_after(self, change, touched: np.ndarray, rows: _Rows | None = None) -> np.ndarray:
        """(N_B,) int32: a vertex after ``change`` is fixed when all the vertices it is
        interpolated from are (a vertex untouched by the change: when it was)."""
        old = self.particle_fixed.numpy()
        sources, weights = change.vertex_rows(touched)
        fixed_touched = np.all((old[sources] == 1) | (weights == 0.0), axis=1)
        fixed = (rows or _Rows())("particle_fixed", old, change.vertex_count_after)
        fixed[touched] = fixed_touched
        return fixed

    def _attachments_after(self, change) -> Attachments:
        """This model's attachments, re-indexed to the vertices after ``change`` (an
        attachment on a deleted vertex loses that weight)."""
        indices = self.attachment_indices.numpy().astype(np.int64)
        weights = self.attachment_weights.numpy().astype(np.float64)
        if not len(indices):  # nothing to re-index: skip the pass over every vertex
            return Attachments(indices, weights, self.attachment_stiffness.numpy())
        kept = _untouched_vertices(change)
        old_to_new = np.full(change.vertex_count_before, -1, dtype=np.int64)
        old_to_new[change.vertex_sources[kept, 0]] = kept
        new_indices = old_to_new[indices] if len(indices) else indices
        weights = np.where(new_indices >= 0, weights, 0.0)
        return Attachments(np.maximum(new_indices, 0), weights, self.attachment_stiffness.numpy())

    @property
    def fixed_count(self) -> int:
        return int(self.particle_fixed.numpy().sum())

    def state(self, requires_grad: bool | None = None) -> State:
        """A new State at rest: positions = rest positions, zero velocity and forces, identity
        rotations. ``requires_grad`` (Newton's keyword) may be None or False: wcut's step is not
        differentiated."""
        _no_gradients("state", requires_grad)
        return State(self)

    def control(self, requires_grad: bool | None = None, clone_variables: bool = True) -> Control:
        """A new Control: attachment targets at the attached rest points (always new arrays;
        Newton's ``clone_variables`` is accepted). ``requires_grad`` as for :meth:`state`."""
        _no_gradients("control", requires_grad)
        return Control(self)


def _no_gradients(what: str, requires_grad) -> None:
    if requires_grad:
        raise ModelError(f"{what}(requires_grad=True): wcut's step is not differentiable (no adjoint kernels); "
                         "use requires_grad=None or False")
