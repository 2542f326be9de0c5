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


@wp.func
def symmetric_eigenvalues(S: wp.mat33):
    """Eigenvalues of a symmetric 3x3 matrix, ascending, in closed form (the trigonometric
    solution of the characteristic cubic; no iteration, no eigenvectors)."""
    off = S[0, 1] * S[0, 1] + S[0, 2] * S[0, 2] + S[1, 2] * S[1, 2]
    q = wp.trace(S) / 3.0
    a = S[0, 0] - q
    b = S[1, 1] - q
    c = S[2, 2] - q
    p2 = a * a + b * b + c * c + 2.0 * off
    if p2 <= 1.0e-24 * (q * q + 1.0e-30):
        return wp.vec3(q, q, q)  # isotropic to rounding
    p = wp.sqrt(p2 / 6.0)
    B = (S - q * wp.identity(3, float)) * (1.0 / p)
    r = wp.clamp(0.5 * wp.determinant(B), -1.0, 1.0)
    phi = wp.acos(r) / 3.0
    largest = q + 2.0 * p * wp.cos(phi)
    smallest = q + 2.0 * p * wp.cos(phi + 2.0943951023931953)  # + 2 pi / 3
    return wp.vec3(smallest, 3.0 * q - largest - smallest, largest)


@wp.func
def axial(H: wp.mat33):
    """Axial vector w of the skew part of H: ``(H - H^T) / 2 = [w]_x``."""
    return 0.5 * wp.vec3(H[2, 1] - H[1, 2], H[0, 2] - H[2, 0], H[1, 0] - H[0, 1])


@wp.func
def rotation_stiffness(V: wp.mat33, mu: float, lam: float):
    """The stiffness of the rotation's variation, the term a corotational solve that holds R
    fixed leaves out, projected to be positive semi-definite (world axes, units of mu).

    With ``P = R sigma(S - I) = 2 mu (F - R) + lam tr(S - I) R`` (``F = R S``), the exact
    differential is ``dP = R sigma(R^T dF) + R [G a]_x`` where ``a`` is the axial vector of the
    skew part of ``R^T dF`` and, from the polar differential ``skew(R^T dF) = (Omega S +
    S Omega) / 2`` with ``dR = R Omega``,

        G = 2 mu I + 2 c (tr(S) I - S)^-1,    c = lam tr(S - I) - 2 mu.

    In world axes (``V = F R^T = R S R^T``, the argument) the term is ``[G_w b]_x R`` with
    ``b = axial(dF R^T)`` and ``G_w = R G R^T``, the same formula in V. Its eigenvalues are
    ``g_i = 2 mu + 2 c / (tr S - s_i)``: zero at rest, positive under tension (the stiffness
    that keeps a taut string straight, without which transverse motion of a stretched element
    is integrated explicitly and goes unstable once ``dt`` exceeds about ``h sqrt(rho/sigma)``),
    negative under compression (buckling). The negative part would make the system matrix
    indefinite, so it is dropped: when the eigenvalues straddle zero the result is the chord
    ``g_max (G - g_min I) / (g_max - g_min)``, which needs only the eigenvalues, is positive
    semi-definite, bounds the projection ``max(g_i, 0)`` from above and is continuous with the
    two pure cases (all ``g_i >= 0``: G itself; all ``<= 0``: zero).
    """
    S = 0.5 * (V + wp.transpose(V))  # V is symmetric up to the iterated rotation's tolerance
    tr = wp.trace(S)
    s = symmetric_eigenvalues(S)
    m_min = tr - s[2]  # eigenvalues of tr(S) I - S
    m_max = tr - s[0]
    zero = wp.mat33(0.0)
    if m_min <= 1.0e-3 * wp.abs(tr) or m_min <= 0.0:
        return zero  # flattened or inverted: no meaningful rotation stiffness
    c = lam * (tr - 3.0) - 2.0 * mu
    G = 2.0 * mu * wp.identity(3, float) + 2.0 * c * wp.inverse(tr * wp.identity(3, float) - S)
    if c >= 0.0:
        return G  # every g_i >= 2 mu
    g_low = 2.0 * mu + 2.0 * c / m_min
    g_high = 2.0 * mu + 2.0 * c / m_max
    if g_low >= 0.0:
        return G
    if g_high <= 0.0:
        return zero
    return (g_high / (g_high - g_low)) * (G - g_low * wp.identity(3, float))
