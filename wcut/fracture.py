"""Stress recovery for fracture on quadratic shells (thesis 6.2), host side in float64.

The fracture criterion of the thesis reads the Cauchy stress of 6-node triangles (VTK
``triangle6`` order: corners 0, 1, 2, then the nodes of edges (0, 1), (1, 2), (2, 0)) at the
nodes of the mesh:

1. the stress is evaluated at the 3 Gauss points of each element and extrapolated to its six
   nodes (:func:`extrapolate_to_nodes`);
2. the element-node values disagree across element boundaries (the stress is a derivative of
   the displacement, which is only continuous there, so it jumps), so each global node gets one tensor:
   the one with the largest maximal principal stress, as the thesis does
   (:func:`smooth_max_principal`), or a weighted mean (:func:`smooth_weighted`);
3. the principal stresses of eq 6.2 in the shell's tangent plane (:func:`principal_stresses`)
   are compared with the ultimate tensile strength, eq 6.3 (:func:`fracture_candidates`);
   the crack runs perpendicular to the principal direction (:func:`crack_direction`).

Stresses are in Pa, as symmetric 3x3 tensors in world axes; a shell is in plane stress, so
the tensors carry no traction on the mid-surface normal and everything is read in the tangent
plane. Bad input (wrong shapes, NaN, out-of-range indices, a non-positive strength) raises
:class:`FractureError` naming the argument and the first bad index.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import FractureError


#: (6, 3) map from the 3 Gauss point values to the 6 node values of the linear field through
#: them (``wcut.shell.GAUSS_POINTS``). The Gauss values are v = GAUSS_POINTS @ a for corner values a, and the inverse of
#: GAUSS_POINTS = I/2 + J/6 (J all ones) is 2 I - J/3: corner i gets (5/3) v_i - (1/3)(v_j + v_k).
#: A linear field at an edge node is the mean of its two corners.
_CORNERS = 2.0 * np.eye(3) - 1.0 / 3.0
EXTRAPOLATION = np.vstack([_CORNERS, 0.5 * (_CORNERS[[0, 1, 2]] + _CORNERS[[1, 2, 0]])])


# --- input checks -------------------------------------------------------------------------

def _float_array(name: str, value, tail: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a finite float64 array whose trailing axes are ``tail`` (None: any length)."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FractureError(f"{name} must be an array of numbers: {exc}") from None
    shape_ok = array.ndim >= len(tail) and all(
        want is None or have == want for have, want in zip(array.shape[array.ndim - len(tail):], tail))
    if not shape_ok:
        expected = ", ".join(["..."] + ["N" if n is None else str(n) for n in tail])
        raise FractureError(f"{name} has shape {array.shape}; expected ({expected})")
    bad = np.argwhere(~np.isfinite(array))
    if len(bad):
        index = tuple(int(i) for i in bad[0])
        raise FractureError(f"{name}{list(index)} is {array[index]}; expected finite values")
    return array


def _unit(name: str, vectors: np.ndarray, problem: str = "has zero length; expected a unit normal") -> np.ndarray:
    """``vectors`` (..., 3) scaled to unit length; a zero vector cannot define a plane."""
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    bad = np.argwhere(length[..., 0] < 1e-12)
    if len(bad):
        raise FractureError(f"{name}{[int(i) for i in bad[0]]} {problem}")
    return vectors / length


def _check_triangles(triangles, node_count: int) -> np.ndarray:
    """(M, 6) integer node indices in [0, node_count), six distinct nodes per element."""
    array = np.asarray(triangles)
    if array.ndim != 2 or array.shape[1] != 6:
        raise FractureError(f"triangles has shape {array.shape}; expected (M, 6)")
    if array.size and not np.issubdtype(array.dtype, np.integer):
        raise FractureError(f"triangles has dtype {array.dtype}; expected integer node indices")
    array = array.astype(np.int64)
    bad = np.argwhere((array < 0) | (array >= node_count))
    if len(bad):
        m, k = (int(i) for i in bad[0])
        raise FractureError(f"triangles[{m}, {k}] = {array[m, k]} is not a node index in [0, {node_count})")
    ordered = np.sort(array, axis=1)
    repeated = np.flatnonzero((ordered[:, 1:] == ordered[:, :-1]).any(axis=1))
    if len(repeated):
        raise FractureError(f"triangles[{repeated[0]}] = {array[repeated[0]].tolist()} repeats a node")
    return array


def _check_node_count(node_count) -> int:
    if isinstance(node_count, bool) or not isinstance(node_count, (int, np.integer)) or node_count < 0:
        raise FractureError(f"node_count = {node_count!r}; expected a non-negative integer")
    return int(node_count)


def _check_node_stress(node_stress, element_count: int) -> np.ndarray:
    stress = _float_array("node_stress", node_stress, (None, 6, 3, 3))
    if stress.ndim != 4 or stress.shape[0] != element_count:
        raise FractureError(f"node_stress has shape {stress.shape}; expected ({element_count}, 6, 3, 3), "
                            "one tensor per element node")
    return stress


# --- recovery -----------------------------------------------------------------------------

def extrapolate_to_nodes(gauss_values) -> np.ndarray:
    """Values at the 6 nodes of each element from its 3 Gauss point values (thesis 6.2).

    The thesis computes the stress at the Gauss points and extrapolates it to the six element
    nodes. The 3 values determine one linear field over the element, which is evaluated at
    the nodes: corner i gets ``(5/3) v_i - (1/3) (v_j + v_k)``, the node of edge (i, j) the
    mean of corners i and j. Any linear field (constant stress included) is reproduced exactly.

    Args:
        gauss_values: (M, 3, ...) values at Gauss point g = barycentric (2/3 at corner g,
            1/6 at the others), any trailing shape, e.g. (M, 3, 3, 3) stresses in Pa.

    Returns:
        (M, 6, ...) values at the nodes in ``triangle6`` order, same units.
    """
    values = _float_array("gauss_values", gauss_values, ())
    if values.ndim < 2 or values.shape[1] != 3:
        raise FractureError(f"gauss_values has shape {values.shape}; expected (M, 3, ...), "
                            "one value per Gauss point")
    return np.einsum("ng,mg...->mn...", EXTRAPOLATION, values)


def tangent_basis(normal) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangent vectors (t1, t2), each (..., 3), with ``t1 x t2 = n``.

    The basis is the branch-free one of Duff et al. (2017, "Building an orthonormal basis,
    revisited"): smooth in the normal except across the plane n_z = 0, and (x, y) for
    n = +z. Principal values and directions do not depend on this choice; only the
    in-plane components s11, s22, s12 do.
    """
    n = _unit("normal", _float_array("normal", normal, (3,)))
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    t2 = np.stack([b, sign + y * y * a, -y], axis=-1)
    return t1, t2


def tangent_components(stress, normal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-plane components (s11, s22, s12) of ``stress`` in the basis :func:`tangent_basis`.

    ``s11 = t1.S t1``, ``s22 = t2.S t2``, ``s12`` from the symmetric part of S (a
    numerically asymmetric tensor does not bias the shear). Shapes broadcast: stress
    (..., 3, 3) in Pa with normal (..., 3); results (...) in Pa. ``s11 + s22`` is the trace
    of the projected tensor, ``tr S - n.S n``.
    """
    return _project(_float_array("stress", stress, (3, 3)), *tangent_basis(normal))


def _project(s: np.ndarray, t1: np.ndarray, t2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    def form(a, b):
        return np.einsum("...i,...ij,...j->...", a, s, b)

    return form(t1, t1), form(t2, t2), 0.5 * (form(t1, t2) + form(t2, t1))


def principal_angle(s11, s22, s12) -> np.ndarray:
    """Angle theta_P (rad, in (-pi/2, pi/2]) from t1 to the direction of sigma_P,+ (eq 6.1).

    The rotation by theta_P makes the shear zero. Eq 6.1 as printed,
    ``theta_P = arctan(2 s12 / (s11 - s22))``, omits the factor 1/2 of the standard result
    ``tan(2 theta_P) = 2 s12 / (s11 - s22)``, and arctan cannot tell the direction of
    sigma_P,+ from that of sigma_P,- (they are 90 degrees apart) nor handle s11 = s22.
    ``theta_P = atan2(2 s12, s11 - s22) / 2`` is the angle of sigma_P,+ in every case; when
    s11 > s22, ``2 theta_P`` equals the printed eq 6.1. For an isotropic state
    (s11 = s22, s12 = 0) every direction is principal and theta_P = 0 (along t1).
    """
    return 0.5 * np.arctan2(2.0 * np.asarray(s12, dtype=np.float64),
                            np.asarray(s11, dtype=np.float64) - np.asarray(s22, dtype=np.float64))


def principal_stresses(stress, normal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal stresses in the tangent plane (eq 6.2) and the direction of the largest.

    ``sigma_P,+- = (s11 + s22)/2 +- sqrt(((s11 - s22)/2)^2 + s12^2)`` with the in-plane
    components of :func:`tangent_components`. The signs are kept: only tension breaks, so
    sigma_P,+ is negative under biaxial compression and 0 under uniaxial compression.
    Invariants: ``sigma_P,+ >= sigma_P,-``, ``sigma_P,+ + sigma_P,- = tr S - n.S n`` and both
    are independent of the tangent basis; rotating S and n by R rotates the direction by R.

    Args:
        stress: (..., 3, 3) symmetric Cauchy stress in world axes, Pa.
        normal: (..., 3) mid-surface normal (normalised here), broadcast against stress:
            element-node stresses (M, 6, 3, 3) take nodal normals ``normals[triangles]``
            (M, 6, 3) or element normals ``normals[:, None]`` (M, 1, 3).

    Returns:
        sigma_plus, sigma_minus (...) in Pa, and direction (..., 3): the unit vector in the
        tangent plane along which sigma_P,+ acts, at angle theta_P (:func:`principal_angle`)
        from t1. Its sign is arbitrary physically; it is fixed so that its component of
        largest magnitude (the first of equal ones) is positive.
    """
    s = _float_array("stress", stress, (3, 3))
    t1, t2 = tangent_basis(normal)
    try:
        np.broadcast_shapes(s.shape[:-2], t1.shape[:-1])
    except ValueError:
        raise FractureError(f"stress {s.shape} and normal {t1.shape} do not broadcast: "
                            "expected (..., 3, 3) and (..., 3) with the same leading axes") from None
    s11, s22, s12 = _project(s, t1, t2)
    mean = 0.5 * (s11 + s22)
    radius = np.hypot(0.5 * (s11 - s22), s12)
    theta = principal_angle(s11, s22, s12)
    direction = np.cos(theta)[..., None] * t1 + np.sin(theta)[..., None] * t2
    return mean + radius, mean - radius, _positive_sign(direction)


def _positive_sign(vectors: np.ndarray) -> np.ndarray:
    """``vectors`` (..., 3) flipped where their component of largest magnitude is negative."""
    largest = np.take_along_axis(vectors, np.argmax(np.abs(vectors), axis=-1)[..., None], axis=-1)
    return np.where(largest < 0.0, -vectors, vectors)


def crack_direction(direction, normal) -> np.ndarray:
    """Unit direction (..., 3) along which a crack opens: ``normalise(n x direction)``.

    A crack opens against the maximal principal stress, so it runs in the tangent plane
    perpendicular to the principal direction of :func:`principal_stresses` (thesis 6.2:
    "material failure in the direction of the rotation angle theta_P"). Dimensionless; the
    sign follows that of ``direction`` (a crack line has no orientation).
    """
    d = _float_array("direction", direction, (3,))
    n = _float_array("normal", normal, (3,))
    return _unit("direction", np.cross(n, d), "is parallel to the normal (or zero); expected a tangent vector")


# --- nodal smoothing ----------------------------------------------------------------------

def smooth_max_principal(triangles, node_stress, normals, node_count) -> np.ndarray:
    """Nodal stress (N, 3, 3) by the thesis rule: the element-node tensor with the largest
    sigma_P,+ among the elements around each node (thesis 6.2, figure 6.12).

    The maximum is conservative: the node breaks as soon as one adjacent element says it
    should. Each sigma_P,+ (eq 6.2) is read in the tangent plane of the node's normal, so all
    candidates at a node are compared in the same plane. Ties go to the lower element index.
    Nodes used by no element get the zero tensor.

    Args:
        triangles: (M, 6) node indices, ``triangle6`` order.
        node_stress: (M, 6, 3, 3) element-node stresses in Pa (:func:`extrapolate_to_nodes`).
        normals: (N, 3) unit normals at the nodes.
        node_count: N.
    """
    n = _check_node_count(node_count)
    tris = _check_triangles(triangles, n)
    stress = _check_node_stress(node_stress, len(tris))
    normals = _float_array("normals", normals, (None, 3))
    if normals.shape != (n, 3):
        raise FractureError(f"normals has shape {normals.shape}; expected ({n}, 3), one per node")
    normals = _unit("normals", normals)
    sigma_plus, _, _ = principal_stresses(stress, normals[tris])
    # Order the element-node entries by node, then by decreasing sigma_P,+, then by position
    # (element index); the first entry of each node wins.
    node_of, sigma, position = tris.ravel(), sigma_plus.ravel(), np.arange(tris.size)
    order = np.lexsort((position, -sigma, node_of))
    used, first = np.unique(node_of[order], return_index=True)
    result = np.zeros((n, 3, 3))
    result[used] = stress.reshape(-1, 3, 3)[order[first]]
    return result


def smooth_weighted(triangles, node_stress, weights, node_count) -> np.ndarray:
    """Nodal stress (N, 3, 3): the weighted mean of the element-node tensors around each node.

    The alternative the thesis suggests for edge nodes, which see only two elements: it
    weighs all attached elements instead of trusting the largest. The recommended weight is
    the element's rest area (m^2): a small sliver then cannot dominate the node, and a
    constant stress field is reproduced exactly whatever the weights. A mean of symmetric
    tensors is symmetric; it is linear, so it smears peaks that the max rule keeps.
    Nodes used by no element get the zero tensor.

    Args:
        triangles: (M, 6) node indices, ``triangle6`` order.
        node_stress: (M, 6, 3, 3) element-node stresses in Pa.
        weights: (M,) positive finite weight per element.
        node_count: N.
    """
    n = _check_node_count(node_count)
    tris = _check_triangles(triangles, n)
    stress = _check_node_stress(node_stress, len(tris))
    w = _float_array("weights", weights, (None,))
    if w.shape != (len(tris),):
        raise FractureError(f"weights has shape {w.shape}; expected ({len(tris)},), one per element")
    bad = np.flatnonzero(w <= 0.0)
    if len(bad):
        raise FractureError(f"weights[{bad[0]}] = {w[bad[0]]}; expected positive weights")
    total = np.zeros((n, 3, 3))
    weight = np.zeros(n)
    np.add.at(total, tris.ravel(), (w[:, None, None, None] * stress).reshape(-1, 3, 3))
    np.add.at(weight, tris.ravel(), np.repeat(w, 6))
    used = weight > 0.0
    total[used] /= weight[used, None, None]
    return total


# --- from a simulation --------------------------------------------------------------------

def nodal_stress(model, state, rule: str = "max") -> tuple[np.ndarray, np.ndarray]:
    """The smoothed nodal stress (N, 3, 3) in Pa of a shell model in ``state``, and the unit
    normals (N, 3) of the deformed surface it is read against.

    ``rule``: ``"max"`` (the thesis: the element value with the highest sigma_P,+) or
    ``"weighted"`` (the rest-area-weighted mean)."""
    (stress,), normals = _nodal_stresses(model, state, (rule,))
    return stress, normals


def _nodal_stresses(model, state, rules, gauss_stress=None) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`nodal_stress` by each of ``rules`` from one stress evaluation (``gauss_stress``,
    (T, 3, 3, 3) Pa, when the caller has it), and the normals."""
    from .shell import vertex_normals
    from .stress import shell_gauss_stress

    for rule in rules:
        if rule not in ("max", "weighted"):
            raise FractureError(f"rule = {rule!r}; expected 'max' or 'weighted'")
    triangles = model.tri_indices.numpy().reshape(-1, 6).astype(np.int64)
    normals = vertex_normals(state.particle_q.numpy().astype(np.float64), triangles)
    gauss_stress = shell_gauss_stress(model, state) if gauss_stress is None else gauss_stress
    node_stress = extrapolate_to_nodes(gauss_stress)
    smoothed = {}
    for rule in set(rules):
        smoothed[rule] = (smooth_max_principal(triangles, node_stress, normals, model.particle_count)
                          if rule == "max" else
                          smooth_weighted(triangles, node_stress, model.tri_rest_area.numpy(), model.particle_count))
    return [smoothed[rule] for rule in rules], normals


# --- criterion ----------------------------------------------------------------------------

def fracture_candidates(sigma_plus, strength) -> np.ndarray:
    """Indices (int64) of the nodes that break, ``sigma_P,+ > sigma_f`` (eq 6.3), most
    stressed first (ties by index).

    Args:
        sigma_plus: (N,) maximal principal stress per node, Pa (may be negative).
        strength: the ultimate tensile strength sigma_f, Pa, finite and > 0 (a material that
            fails under no tension at all is not a material).
    """
    sigma = _float_array("sigma_plus", sigma_plus, (None,))
    if sigma.ndim != 1:
        raise FractureError(f"sigma_plus has shape {sigma.shape}; expected (N,), one value per node")
    if isinstance(strength, bool) or not isinstance(strength, (int, float, np.integer, np.floating)):
        raise FractureError(f"strength = {strength!r}; expected a number (Pa)")
    if not (np.isfinite(strength) and strength > 0.0):
        raise FractureError(f"strength = {strength!r} Pa; expected a finite positive tensile strength")
    broken = np.flatnonzero(sigma > strength)
    return broken[np.argsort(-sigma[broken], kind="stable")].astype(np.int64)


# --- crack propagation --------------------------------------------------------------------

#: How a crack follows its direction (thesis 6.2, figure 6.16, and its future work):
#: ``"none"`` opens the existing edge closest to the crack direction; ``"spatial"`` also snaps
#: the edge's far corner to the crack line drawn in the rest configuration with the deformed
#: direction (figure 6.16, middle); ``"material"`` snaps it to the crack line mapped to the
#: rest configuration through the element (figure 6.14; figure 6.16, right); ``"split"``
#: first splits the triangle ahead of the tip into four (red-green refinement, exact
#: geometry) and snaps only nodes the refinement made corners, so the coarse mesh never moves.
VARIANTS = ("none", "spatial", "material", "split")


@dataclass(frozen=True)
class CrackEvent:
    """One advance of a crack: the edges opened at a node in one fracture step.

    Attributes:
        step: the fracture step (call of :meth:`ShellFracture.step`, from 0).
        node: the corner the crack advanced from (index before the event).
        sigma_plus: its maximal principal stress (Pa).
        direction: (3,) unit crack direction in the rest configuration that the edges were
            chosen against (the deformed direction for ``"none"`` and ``"spatial"``, mapped
            to the rest configuration for ``"material"`` and ``"split"``).
        segments: (k, 2, 3) rest positions (m) of the opened edges' corners, from the node.
        initiation: True when the node had no opened edge (the crack starts there).
        snapped: True when a far corner was moved onto the crack line.
        refined: True when a triangle was split before the edge was chosen.
    """

    step: int
    node: int
    sigma_plus: float
    direction: np.ndarray
    segments: np.ndarray
    initiation: bool
    snapped: bool
    refined: bool


class ShellFracture:
    """Fracture of a quadratic shell driven by the maximal principal stress (thesis 6.2).

    Each :meth:`step` reads the smoothed nodal stress, takes the corners where
    ``sigma_P,+ > strength`` (eq 6.3), most stressed first, and advances at most
    ``max_cracks_per_step`` of them: at a corner on the boundary (a crack tip, a notch, a
    free edge) it opens the one interior edge closest to the crack direction; inside the
    sheet it opens the two edges closest to either way along it, so the crack starts with two
    tips. "Closest" is the thesis's rule of figure 6.13 (dark green): the smallest angle
    between the crack direction and the vector from the node to the edge's far corner. The
    crack direction is perpendicular to the principal direction in the tangent plane
    (:func:`crack_direction`). Boundary and fixed nodes are never snapped. Nodes touched by one
    advance are not advanced again in the same step (their stress is stale).

    Args:
        mesh: the rest mesh of the model the steps will be given.
        strength: ultimate tensile strength sigma_f (Pa), > 0.
        variant: one of :data:`VARIANTS`.
        max_cracks_per_step: the most advances per step (>= 1): a bound on crack speed,
            ``max_cracks_per_step`` edges per tip per step at most.
        smoothing: the nodal stress the criterion reads: ``"max"`` (the thesis) or
            ``"weighted"`` (:func:`nodal_stress`).
        direction_smoothing: the nodal stress the crack direction is read from, default
            ``"weighted"``: the max rule hands a node the tensor of a single element beside it,
            whose principal direction near a crack tip is tilted by the singular field (10 to
            25 degrees on the precut sheet), while the area-weighted mean around the tip is
            symmetric and gives the mode-I direction.
        min_quality: the smallest corner-triangle quality a snap or a split may leave
            (:data:`wcut.topology.shell.MIN_MOVE_QUALITY`); below it the snap or split is
            skipped and the crack opens the existing edge.

    Attributes:
        mesh: the current rest mesh (after every change so far).
        events: the :class:`CrackEvent` of every advance, in order.
        rest_area: the sheet's rest area (m^2) at the start. Opening and splitting keep it
            exactly; a snap keeps it on a flat sheet, and on a curved one moves nodes on the
            element surfaces, which re-interpolates the curved geometry (relative area
            changes of 1e-7 on a 6 cm cylinder).
    """

    def __init__(self, mesh, strength, *, variant: str = "none", max_cracks_per_step: int = 1,
                 smoothing: str = "max", direction_smoothing: str = "weighted", min_quality: float | None = None):
        from .mesh import ShellMesh
        from .topology.shell import MIN_MOVE_QUALITY

        if not isinstance(mesh, ShellMesh):
            raise FractureError(f"mesh: expected a ShellMesh, got {type(mesh).__name__}")
        fracture_candidates(np.zeros(1), strength)  # the strength checks
        if variant not in VARIANTS:
            raise FractureError(f"variant = {variant!r}; expected one of {', '.join(VARIANTS)}")
        if isinstance(max_cracks_per_step, bool) or not isinstance(max_cracks_per_step, (int, np.integer)) \
                or max_cracks_per_step < 1:
            raise FractureError(f"max_cracks_per_step = {max_cracks_per_step!r}; expected an integer >= 1")
        for name, rule in (("smoothing", smoothing), ("direction_smoothing", direction_smoothing)):
            if rule not in ("max", "weighted"):
                raise FractureError(f"{name} = {rule!r}; expected 'max' or 'weighted'")
        min_quality = MIN_MOVE_QUALITY if min_quality is None else float(min_quality)
        if not 0.0 <= min_quality < 1.0:
            raise FractureError(f"min_quality = {min_quality}; expected a value in [0, 1)")
        self.mesh = mesh
        self.strength = float(strength)
        self.variant = variant
        self.max_cracks_per_step = int(max_cracks_per_step)
        self.smoothing = smoothing
        self.direction_smoothing = direction_smoothing
        self.min_quality = min_quality
        self.rest_area = mesh.area()
        self.events: list[CrackEvent] = []
        self._step = 0
        self._tips: set[int] = set()  # far corners of the edges opened so far
        # corners of the mesh as given: the split variant never moves them
        self._pinned = np.zeros(mesh.vertex_count, dtype=bool)
        self._pinned[mesh.corner_ids] = True
        self._split_area = 0.3 * float(mesh.areas().mean())  # below it a triangle is refined already

    def step(self, model, state):
        """Advance the cracks of ``model`` (built from :attr:`mesh`) in ``state``.

        Returns the :class:`wcut.topology.TopologyChange` from the model's mesh to the new
        :attr:`mesh` (give both to :meth:`wcut.model.Model.rebuild`), or None when nothing
        broke."""
        from .topology.change import compose

        if model.particle_count != self.mesh.vertex_count or model.tri_count != self.mesh.triangle_count:
            raise FractureError(f"step: the model ({model.particle_count} nodes, {model.tri_count} triangles) is "
                                f"not built from this fracture's mesh ({self.mesh.vertex_count} nodes, "
                                f"{self.mesh.triangle_count} triangles); rebuild it after every change")
        from .stress import shell_gauss_stress

        step, self._step = self._step, self._step + 1
        gauss_stress = shell_gauss_stress(model, state)
        # No node value exceeds 7/3 of the largest Gauss-point tensor (the extrapolation's row
        # sums of magnitudes, 5/3 + 1/3 + 1/3), and sigma_P,+ <= |S|_F: far from breaking,
        # the smoothing is skipped.
        if 7.0 / 3.0 * np.sqrt(np.einsum("tgij,tgij->tg", gauss_stress, gauss_stress).max()) <= self.strength:
            return None
        (stress, oriented), normals = _nodal_stresses(model, state, (self.smoothing, self.direction_smoothing),
                                                      gauss_stress)
        corners = self.mesh.corner_ids
        sigma_plus, _, _ = principal_stresses(stress[corners], normals[corners])
        _, _, principal = principal_stresses(oriented[corners], normals[corners])
        broken = fracture_candidates(sigma_plus, self.strength)
        if not len(broken):
            return None
        fixed = model.particle_fixed.numpy() == 1
        x = state.particle_q.numpy().astype(np.float64)
        mesh, change, stale, count = self.mesh, None, set(), 0
        for i in broken.tolist():
            v = int(corners[i])
            if count == self.max_cracks_per_step:
                break
            if v in stale:
                continue
            d = crack_direction(principal[i], normals[v])
            advance = _Advance(self, mesh, x, fixed, v, d)
            result = advance.run()
            if result is None:
                continue
            mesh, event_change = result
            stale |= advance.touched
            x, fixed, self._pinned = advance.x, advance.fixed, advance.pinned  # carried through the event
            change = event_change if change is None else compose(change, event_change)
            self.events.append(CrackEvent(step=step, node=v, sigma_plus=float(sigma_plus[i]),
                                          direction=advance.direction, segments=advance.segments(mesh),
                                          initiation=advance.initiation, snapped=advance.snapped,
                                          refined=advance.refined))
            count += 1
        self.mesh = mesh
        return change


def _carry(values: np.ndarray, change) -> np.ndarray:
    """Per-vertex ``values`` (N, k) after ``change`` (its vertex weights)."""
    return np.einsum("vk,vkj->vj", change.vertex_weights, values[change.vertex_sources])


def _unit_vector(v: np.ndarray) -> np.ndarray | None:
    n = np.linalg.norm(v)
    return v / n if n > 1e-300 else None


class _Advance:
    """One advance of a crack at corner ``v`` with deformed crack direction ``d``: refine
    (split variant), choose the edges, snap their far corners, open the edges."""

    def __init__(self, fracture: ShellFracture, mesh, x, fixed, v: int, d: np.ndarray):
        self.fracture, self.mesh, self.x, self.fixed, self.v, self.d = fracture, mesh, x, fixed, v, d
        self.snapped = self.refined = False
        self.touched: set[int] = set()
        self.change = None
        self.edges: list[tuple[int, int]] = []

    # -- the mesh around v -------------------------------------------------------------------

    def _users(self):
        from .topology.shell import edge_users

        return edge_users(self.mesh.triangles)

    def _around(self, v: int) -> list[int]:
        return np.flatnonzero((self.mesh.triangles == v).any(axis=1)).tolist()

    def _boundary_corners(self, users) -> set[int]:
        return {c for key, u in users.items() if len(u) == 1 for c in key}

    def _apply(self, result) -> None:
        from .topology.change import compose

        self.mesh, change = result
        self.x = _carry(self.x, change)
        self.fixed = _carry(self.fixed[:, None].astype(float), change)[:, 0] == 1.0
        self.pinned = _carry(self.pinned[:, None].astype(float), change)[:, 0] == 1.0
        self.change = change if self.change is None else compose(self.change, change)

    # -- direction ---------------------------------------------------------------------------

    def _material_direction(self, users) -> tuple[np.ndarray, int]:
        """The crack direction in the rest configuration (figure 6.14): a point a quarter of
        an edge along the deformed crack line is located in the element it lies in, and its
        material point gives the direction. Returns it and that element (the one ahead).

        At a boundary corner the point is taken on the side of the line that goes into the
        sheet: at a crack tip the other side also lies in the sheet (on a face of the opened
        crack), and a direction read there, through the opening, is distorted."""
        from .shell import vertex_normals
        from .topology.shell import locate

        v, x, X, tris = self.v, self.x, self.mesh.vertices, self.mesh.triangles
        around = self._around(v)
        corners = np.unique(tris[around, :3])
        step = 0.25 * float(np.mean(np.linalg.norm(x[corners] - x[v], axis=1)[corners != v]))
        sign = 1.0
        if not self._interior_of(v, users) and self.d @ self._inward(users, x) < 0.0:
            sign = -1.0
        t, L, _ = locate(x, tris, around, x[v] + sign * step * self.d)
        material = shell_point(X, tris, t, L) - X[v]
        normal = vertex_normals(X, tris[around])[v]
        D = _unit_vector(material - (material @ normal) * normal)
        return (sign * D if D is not None else self.d), t

    # -- the advance -------------------------------------------------------------------------

    def run(self):
        from .topology.mesh import TopologyError
        from .topology.shell import move_nodes, open_edges

        f, v = self.fracture, self.v
        self.pinned = f._pinned
        users = self._users()
        self.initiation = v not in f._tips
        material = f.variant in ("material", "split")
        if material:
            self.direction, ahead = self._material_direction(users)
        else:
            self.direction, ahead = self.d, -1
        if f.variant == "split":
            self._refine(ahead, users)
            users = self._users()
        points = self.mesh.vertices if material else self.x
        edges = self._choose(users, points)
        if edges is None:
            return None
        moves = self._snap_moves(edges, users)
        if moves:
            try:
                self._apply(move_nodes(self.mesh, moves, f.min_quality))
                self.snapped = True
            except TopologyError:
                pass
        for _, w in edges:
            self.touched |= set(np.unique(self.mesh.triangles[self._around(v) + self._around(w)]).tolist())
        try:
            self._apply(open_edges(self.mesh, edges))
        except TopologyError:
            return None
        self.edges = edges
        f._tips.discard(v)
        f._tips.update(w for _, w in edges)
        return self.mesh, self.change

    def _interior_of(self, v, users) -> bool:
        return not any(len(u) == 1 for key, u in users.items() if v in key)

    def _refine(self, ahead: int, users) -> None:
        """Split the triangle ahead of the tip (the one the crack direction enters) into four
        when it is not refined already and every piece keeps its quality."""
        from .topology.mesh import TopologyError
        from .topology.shell import split_triangle, triangle_qualities

        f = self.fracture
        if ahead < 0 or self.mesh.areas()[ahead] < f._split_area:
            return
        try:
            mesh, change = split_triangle(self.mesh, ahead)
        except TopologyError:
            return
        pieces = np.flatnonzero(change.element_rest_changed)
        if triangle_qualities(mesh.vertices, mesh.triangles[pieces]).min() < f.min_quality:
            return
        self._apply((mesh, change))
        self.touched |= set(np.unique(mesh.triangles[pieces]).tolist())
        self.refined = True

    def _choose(self, users, points) -> list[tuple[int, int]] | None:
        """The edges to open (figure 6.13, dark green): from ``v``, the interior edge whose far
        corner makes the smallest angle with the crack line (one edge at a boundary node, the
        best on either side inside the sheet)."""
        v, D = self.v, self.direction
        options = []
        for key, u in users.items():
            if v in key and len(u) == 2:
                w = key[0] if key[1] == v else key[1]
                e = _unit_vector(points[w] - points[v])
                if e is not None:
                    options.append((float(e @ D), w))
        if not options:
            return None
        if not self._interior_of(v, users):  # one edge, into the sheet
            sign = 1.0 if D @ self._inward(users, points) >= 0.0 else -1.0
            ahead = [(sign * c, w) for c, w in options if sign * c > 0.0]
            return [(v, max(ahead, key=lambda o: (o[0], -o[1]))[1])] if ahead else None
        ahead = [o for o in options if o[0] > 0.0]
        behind = [o for o in options if o[0] < 0.0]
        if not ahead or not behind:
            return None
        return [(v, max(ahead, key=lambda o: (o[0], -o[1]))[1]), (v, min(behind, key=lambda o: (o[0], o[1]))[1])]

    def _inward(self, users, points) -> np.ndarray:
        """A direction from boundary corner ``v`` into the sheet: away from its boundary edges
        (at a crack tip both run back along the crack), or, where they cancel (a straight
        edge), towards the middle of its triangles."""
        v = self.v
        back = np.zeros(3)
        for key, u in users.items():
            if v in key and len(u) == 1:
                e = _unit_vector(points[key[0] + key[1] - v] - points[v])
                back += e if e is not None else 0.0
        if np.linalg.norm(back) > 0.5:
            return -back
        return points[self.mesh.triangles[self._around(v), :3]].mean(axis=(0, 1)) - points[v]

    def _snap_moves(self, edges, users) -> dict:
        """The moves that put each edge's far corner on the crack line through ``v`` (and the
        edge nodes of its edges halfway again), for a variant that snaps; boundary, fixed
        and (split variant) original corners stay."""
        from .shell import vertex_normals
        from .topology.shell import locate, shape_weights

        f = self.fracture
        if f.variant == "none":
            return {}
        boundary = self._boundary_corners(users)
        X, x, tris, v = self.mesh.vertices, self.x, self.mesh.triangles, self.v
        moves = {}
        for _, w in edges:
            if w in boundary or self.fixed[w] or (f.variant == "split" and self.pinned[w]):
                continue
            around = self._around(w)
            if f.variant == "spatial":
                # the deformed line, and the same direction drawn in the rest configuration
                normal = vertex_normals(X, tris[self._around(v)])[v]
                d_rest = _unit_vector(self.d - (self.d @ normal) * normal)
                if d_rest is None:
                    continue
                rest_w = X[v] + ((X[w] - X[v]) @ d_rest) * d_rest
                rest_w = shell_point(X, tris, *locate(X, tris, around, rest_w)[:2])  # onto the surface
                now_w = x[v] + ((x[w] - x[v]) @ self.d) * self.d
                t, L, _ = locate(x, tris, around, now_w)
            else:
                rest_w = X[v] + ((X[w] - X[v]) @ self.direction) * self.direction
                t, L, _ = locate(X, tris, around, rest_w)
                rest_w = shell_point(X, tris, t, L)
            moves[w] = (rest_w, shape_weights(tris, t, L))
            for tri in tris[around].tolist():  # the edge nodes of w's edges follow it
                for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
                    if w not in (tri[i], tri[j]) or tri[3 + k] in moves:
                        continue
                    m = tri[3 + k]
                    rest_m = X[m] + 0.5 * (rest_w - X[w])
                    config = x if f.variant == "spatial" else X
                    target = config[m] + 0.5 * (shell_point(config, tris, t, L) - config[w])
                    tm, Lm, _ = locate(config, tris, around, target)
                    moves[m] = (rest_m if f.variant == "spatial" else shell_point(X, tris, tm, Lm),
                                shape_weights(tris, tm, Lm))
            self.touched |= set(np.unique(tris[around]).tolist())
        return moves

    def segments(self, mesh) -> np.ndarray:
        """(k, 2, 3) rest positions of the opened edges' corners in ``mesh``, node first."""
        X = mesh.vertices
        return np.array([[X[a], X[b]] for a, b in self.edges])


def shell_point(points: np.ndarray, triangles: np.ndarray, t: int, L: np.ndarray) -> np.ndarray:
    """The point (3,) of element ``t`` at barycentric ``L`` with node positions ``points``."""
    from .shell import shape_functions

    return shape_functions(L)[0] @ points[triangles[t]]
