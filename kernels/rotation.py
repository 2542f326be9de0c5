"""Rotation extraction for the corotational formulation (thesis eq. 3.49).

The corotational element needs, per element (or per Gauss point), the rotation ``R`` of the
polar decomposition ``F = R S`` of the deformation gradient. Two methods:

- :func:`polar_rotation`, used by the solver: maximises ``tr(R^T F)`` over proper rotations
  by axis-angle updates of a unit quaternion, as in Mueller, Bender, Chentanez and Macklin,
  "A robust method to extract the rotational part of deformations" (MIG 2016), but with a
  Newton step: with ``A = R^T F``, the gradient of ``tr(exp(d)^T A)`` at ``d = 0`` is the
  axial vector ``w`` of ``A - A^T`` and its Hessian is ``sym(A) - tr(A) I``, so the step is
  ``d = (tr(A) I - sym(A))^-1 w``. Mueller's step ``w / |tr(A)|`` equals it only for
  ``A = I``; near a stretched element it converges linearly (error times ~1/3 per iteration),
  Newton's quadratically, so a warm-started step needs one or two iterations. Where the
  Hessian is not negative definite (far from the maximiser: inverted or cold-started) the
  update falls back to Mueller's step, which always ascends, and when ``tr(A) < 0`` (more than a
  quarter turn from the warm start, where at exactly a half turn the gradient vanishes) it first
  jumps by the half turn about the frame axis that raises the trace most. It never produces a
  reflection and stays defined for flat (rank-deficient) and inverted ``F``.
- :func:`svd_rotation`, the reference it is measured against: ``R = U V^T`` from the SVD
  with the column of ``U`` of the smallest singular value negated when ``det(U V^T) < 0``
  (the closest proper rotation, as in invertible FEM). For ``det F > 0`` both give the polar
  rotation; for inverted ``F`` both give the maximiser of ``tr(R^T F)``.
"""

import warp as wp


@wp.func
def polar_rotation(F: wp.mat33, q_start: wp.quat, max_iterations: int, tolerance: float):
    """Proper rotation maximising tr(R^T F), as a unit quaternion, warm-started at ``q_start``.

    Stops when the remaining angle error is estimated at most ``tolerance`` (radians): an update
    below it, or a Newton update ``d`` with ``|d|^2`` below it, since Newton then leaves an
    error of order ``|d|^2``; or after ``max_iterations``.
    """
    q = wp.normalize(q_start)
    for _ in range(max_iterations):
        A = wp.transpose(wp.quat_to_matrix(q)) * F  # F in the current frame
        t = wp.trace(A)
        if t < 0.0:
            # More than a quarter turn away (e.g. an object rotated by 180 degrees since the
            # warm start, where the gradient vanishes): jump by the half turn about the frame
            # axis that raises the trace most, tr(Rot_i(pi)^T A) = 2 A_ii - tr(A).
            k = int(0)
            if A[1, 1] > A[k, k]:
                k = 1
            if A[2, 2] > A[k, k]:
                k = 2
            if 2.0 * A[k, k] - t > t:
                axis = wp.vec3(0.0)
                axis[k] = 1.0
                q = wp.normalize(q * wp.quat(axis[0], axis[1], axis[2], 0.0))
                A = wp.transpose(wp.quat_to_matrix(q)) * F
                t = wp.trace(A)
        w = wp.vec3(A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1])
        # H = tr(A) I - sym(A): positive definite near the maximiser (leading minors > 0)
        h00 = t - A[0, 0]
        h11 = t - A[1, 1]
        h01 = -0.5 * (A[0, 1] + A[1, 0])
        H = wp.mat33(h00, h01, -0.5 * (A[0, 2] + A[2, 0]),
                     h01, h11, -0.5 * (A[1, 2] + A[2, 1]),
                     -0.5 * (A[0, 2] + A[2, 0]), -0.5 * (A[1, 2] + A[2, 1]), t - A[2, 2])
        det = wp.determinant(H)
        newton = h00 > 0.0 and h00 * h11 - h01 * h01 > 0.0 and det > 1.0e-12 * t * t * t
        d = w / (wp.abs(t) + 1.0e-9)
        if newton:
            d = wp.inverse(H) * w
        angle_sq = wp.dot(d, d)
        if angle_sq <= tolerance * tolerance:
            break
        if angle_sq > 1.0:  # a trust region: at most ~57 degrees per update
            d = d / wp.sqrt(angle_sq)
        # second-order retraction: normalize(1, d/2) is exp(d) up to O(|d|^3), which keeps
        # Newton's quadratic convergence without the sine and cosine of an axis-angle update
        q = wp.normalize(q * wp.quat(0.5 * d[0], 0.5 * d[1], 0.5 * d[2], 1.0))
        if newton and angle_sq <= tolerance:
            break  # quadratic convergence: the error left after this step is about |d|^2
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
