"""Rotation extraction for the corotational formulation (thesis eq. 3.49).

The corotational element needs, per element (or per Gauss point), the rotation ``R`` of the
polar decomposition ``F = R S`` of the deformation gradient. Two methods:

- :func:`polar_rotation`, used by the solver: the iteration of Mueller, Bender, Chentanez and
  Macklin, "A robust method to extract the rotational part of deformations" (MIG 2016). It
  maximises ``tr(R^T F)`` over proper rotations by repeated axis-angle updates of a unit
  quaternion. It never produces a reflection, stays defined for flat (rank-deficient) and
  inverted ``F``, and is warm-started with the previous step's rotation, so one or two
  iterations usually reach the tolerance during a simulation.
- :func:`svd_rotation`, the reference it is measured against: ``R = U V^T`` from the SVD
  with the column of ``U`` of the smallest singular value negated when ``det(U V^T) < 0``
  (the closest proper rotation, as in invertible FEM). For ``det F > 0`` both give the polar
  rotation; for inverted ``F`` both give the maximiser of ``tr(R^T F)``.
"""

import warp as wp


@wp.func
def polar_rotation(F: wp.mat33, q_start: wp.quat, max_iterations: int, tolerance: float):
    """Proper rotation maximising tr(R^T F), as a unit quaternion, warm-started at ``q_start``.

    Stops when the axis-angle correction is below ``tolerance`` (radians) or after
    ``max_iterations`` updates.
    """
    q = wp.normalize(q_start)
    Ft = wp.transpose(F)  # rows of Ft are the columns of F
    for _ in range(max_iterations):
        Rt = wp.transpose(wp.quat_to_matrix(q))
        omega = wp.cross(Rt[0], Ft[0]) + wp.cross(Rt[1], Ft[1]) + wp.cross(Rt[2], Ft[2])
        omega = omega / (wp.abs(wp.dot(Rt[0], Ft[0]) + wp.dot(Rt[1], Ft[1]) + wp.dot(Rt[2], Ft[2])) + 1.0e-9)
        w = wp.length(omega)
        if w < tolerance:
            break
        q = wp.normalize(wp.quat_from_axis_angle(omega / w, w) * q)
    return q


@wp.func
def svd_rotation(F: wp.mat33):
    """Closest proper rotation to F from its SVD (reference for :func:`polar_rotation`)."""
    U, sigma, V = wp.svd3(F)
    R = U * wp.transpose(V)
    if wp.determinant(R) < 0.0:
        # negate the singular direction of the smallest singular value
        k = int(0)
        if wp.abs(sigma[1]) < wp.abs(sigma[k]):
            k = 1
        if wp.abs(sigma[2]) < wp.abs(sigma[k]):
            k = 2
        D = wp.identity(3, float)
        D[k, k] = -1.0
        R = U * D * wp.transpose(V)
    return R


@wp.kernel
def extract_rotations(
    F: wp.array(dtype=wp.mat33),
    q_start: wp.array(dtype=wp.quat),
    max_iterations: int,
    tolerance: float,
    R_out: wp.array(dtype=wp.mat33),
):
    """Polar rotations of a batch of 3x3 matrices (for tests and benchmarks)."""
    i = wp.tid()
    R_out[i] = wp.quat_to_matrix(polar_rotation(F[i], q_start[i], max_iterations, tolerance))


@wp.kernel
def extract_rotations_svd(F: wp.array(dtype=wp.mat33), R_out: wp.array(dtype=wp.mat33)):
    """SVD rotations of a batch of 3x3 matrices (for tests and benchmarks)."""
    i = wp.tid()
    R_out[i] = svd_rotation(F[i])
