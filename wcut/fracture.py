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
    from .shell import vertex_normals
    from .stress import shell_gauss_stress

    if rule not in ("max", "weighted"):
        raise FractureError(f"rule = {rule!r}; expected 'max' or 'weighted'")
    triangles = model.tri_indices.numpy().reshape(-1, 6).astype(np.int64)
    normals = vertex_normals(state.particle_q.numpy().astype(np.float64), triangles)
    node_stress = extrapolate_to_nodes(shell_gauss_stress(model, state))
    if rule == "max":
        return smooth_max_principal(triangles, node_stress, normals, model.particle_count), normals
    return smooth_weighted(triangles, node_stress, model.tri_rest_area.numpy(), model.particle_count), normals


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
