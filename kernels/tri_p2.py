"""Corotational quadratic triangles (6 nodes): the plane-stress membrane of a thin shell.

Node order is VTK triangle6: corners 0, 1, 2, then the nodes of edges (0, 1), (1, 2), (2, 0).
Reference coordinates are ``xi = (L1, L2)``. Quadrature: the 3-point rule of degree 2, Gauss
point ``g`` at barycentric coordinate 2/3 on corner g and 1/6 on the others, weight 1/6 (of the
reference area 1/2); exact for the stiffness of a straight element (thesis 6.2 computes the
stress at these points and extrapolates it to the nodes, ``wcut.fracture``).

Per element and Gauss point (set up by ``wcut.model.Model`` from a ``ShellMesh``):

- ``tri_poses[e, g] = J^{-1}`` (1/m), the inverse of the rest Jacobian ``J = E^T dX/dxi``,
  where ``E = [E1 | E2]`` is an orthonormal basis of the rest tangent plane at the point;
  so the columns of ``F = (dx/dxi) J^{-1}`` (3x2) are the images of ``E1`` and ``E2``;
- ``tri_stiffness[e, g] = w_g |det J| h (mu, lambda*)`` (N*m): the point's share of the rest
  area times the thickness ``h`` times the plane-stress Lame parameters,
  ``lambda* = 2 mu lambda / (lambda + 2 mu)`` (the 3D lambda with ``sigma_33 = 0``).

Corotational membrane (thesis eq. 3.49 in the tangent plane): the polar decomposition
``F = R S`` gives ``R`` (3x2, orthonormal columns) and the stretch ``S`` (2x2, symmetric
positive definite) in closed form, ``S = (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C))``
with ``C = F^T F``: no iteration and no warm start. The strain is ``S - I`` and the stress
``sigma = mu (e + e^T) + lambda* tr(e) I``; the force on node a is
``f_a = -sum_g A_g h R sigma_g grad N_a`` with ``grad N_a = J^{-T} dN_a/dxi``.

Stiffness used by the implicit solver: the corotated ``R K R^T`` (rotation held fixed, as for
the tetrahedra) plus the geometric (initial-stress) stiffness of the tension,
``K_geo,ab = sum_g A_g h (grad N_a . sigma+ grad N_b) I``, with ``sigma+`` the tensile part of the
stress (negative principal stresses dropped so the matrix stays positive semi-definite). A
membrane has no in-plane stiffness against moving out of its plane; without ``K_geo`` a taut
sheet's transverse motion would be integrated explicitly and ring at large time steps.
Bending is a separate energy on hinges (``wcut.kernels.bending``).
"""

import warp as wp

vec6i = wp.types.vector(length=6, dtype=wp.int32)
mat32 = wp.types.matrix(shape=(3, 2), dtype=float)
mat62 = wp.types.matrix(shape=(6, 2), dtype=float)
mat63 = wp.types.matrix(shape=(6, 3), dtype=float)

GAUSS_A = wp.constant(2.0 / 3.0)
GAUSS_B = wp.constant(1.0 / 6.0)


@wp.func
def gauss_point(g: int):
    """Barycentric coordinates (L0, L1, L2) of Gauss point g."""
    L = wp.vec3(GAUSS_B)
    L[g] = GAUSS_A
    return L


@wp.func
def shape_gradients(L: wp.vec3):
    """Row a: ``dN_a/dxi`` (xi = (L1, L2)) at barycentric point L, for the 6 shape functions
    ``N_k = L_k (2 L_k - 1)`` (corners) and ``N_ij = 4 L_i L_j`` (edge nodes)."""
    dL = mat63()  # dN_a/dL_k
    dL[0, 0] = 4.0 * L[0] - 1.0
    dL[1, 1] = 4.0 * L[1] - 1.0
    dL[2, 2] = 4.0 * L[2] - 1.0
    dL[3, 0] = 4.0 * L[1]
    dL[3, 1] = 4.0 * L[0]
    dL[4, 1] = 4.0 * L[2]
    dL[4, 2] = 4.0 * L[1]
    dL[5, 2] = 4.0 * L[0]
    dL[5, 0] = 4.0 * L[2]
    dN = mat62()
    for a in range(6):
        dN[a] = wp.vec2(dL[a, 1] - dL[a, 0], dL[a, 2] - dL[a, 0])
    return dN


@wp.func
def gather(x: wp.array(dtype=wp.vec3), t: vec6i):
    """The six nodal vectors of an element, as rows."""
    X = mat63()
    for a in range(6):
        X[a] = x[t[a]]
    return X


@wp.func
def reference_gradient(X: mat63, dN: mat62):
    """``dx/dxi`` (3x2) of the nodal field X."""
    G = mat32()
    for a in range(6):
        G = G + wp.outer(X[a], dN[a])
    return G


@wp.func
def scatter(t: vec6i, Q: mat32, dN: mat62, y: wp.array(dtype=wp.vec3)):
    """``y[t[a]] += Q dN_a/dxi``: the nodal vectors of a stress-like Q conjugate to xi."""
    for a in range(6):
        wp.atomic_add(y, t[a], Q * dN[a])


@wp.func
def polar_rotation(F: mat32):
    """R (3x2, orthonormal columns) of the polar decomposition ``F = R S``, in closed form.

    A collapsed element (rank of F below 2) has no polar rotation; it gets the Gram-Schmidt
    frame of its longest column, so the stress stays finite and pushes it open again."""
    C = wp.transpose(F) * F
    s = wp.sqrt(wp.max(wp.determinant(C), 0.0))
    trace = C[0, 0] + C[1, 1]
    if s > 1.0e-6 * trace:
        S_inv = wp.inverse((C + s * wp.identity(2, float)) * (1.0 / wp.sqrt(trace + 2.0 * s)))
        return F * S_inv
    f0 = wp.vec3(F[0, 0], F[1, 0], F[2, 0])
    f1 = wp.vec3(F[0, 1], F[1, 1], F[2, 1])
    flip = wp.length_sq(f1) > wp.length_sq(f0)
    a = f0
    if flip:
        a = f1
    if wp.length_sq(a) == 0.0:
        a = wp.vec3(1.0, 0.0, 0.0)
    a = wp.normalize(a)
    helper = wp.vec3(0.0, 0.0, 1.0)
    if wp.abs(a[2]) > 0.9:
        helper = wp.vec3(1.0, 0.0, 0.0)
    b = wp.normalize(wp.cross(helper, a))
    if flip:
        return wp.matrix_from_cols(b, a)
    return wp.matrix_from_cols(a, b)


@wp.func
def hooke(G: wp.mat22, mu: float, lam: float):
    """Plane stress of a 2x2 displacement gradient G (lam is the plane-stress lambda*)."""
    return mu * (G + wp.transpose(G)) + (lam * wp.trace(G)) * wp.identity(2, float)


@wp.func
def tensile_part(s: wp.mat22):
    """The symmetric 2x2 tensor with the negative principal values of s set to zero."""
    half_sum = 0.5 * (s[0, 0] + s[1, 1])
    half_diff = 0.5 * (s[0, 0] - s[1, 1])
    offdiag = 0.5 * (s[0, 1] + s[1, 0])
    radius = wp.sqrt(half_diff * half_diff + offdiag * offdiag)
    high = half_sum + radius
    low = half_sum - radius
    if low >= 0.0:
        return s
    if high <= 0.0:
        return wp.mat22(0.0)
    # eigenvector of the high value: (cos t, sin t), 2t = atan2(offdiag, half_diff)
    t = 0.5 * wp.atan2(offdiag, half_diff)
    d = wp.vec2(wp.cos(t), wp.sin(t))
    return high * wp.outer(d, d)


@wp.kernel
def tri_forces(
    tri_indices: wp.array(dtype=vec6i),
    tri_poses: wp.array2d(dtype=wp.mat22),
    tri_stiffness: wp.array2d(dtype=wp.vec2),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    velocity_scale: float,
    matrix_scale: float,
    tri_rotation: wp.array2d(dtype=mat32),
    tri_tension: wp.array2d(dtype=wp.mat22),
    particle_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
):
    """Per element, once per step: rotations and tension at the Gauss points, and the same
    three terms as ``tet_p1.tet_forces`` with ``K`` the membrane's corotated plus geometric
    stiffness: ``particle_f += f(x) - c_v K v`` and ``particle_diagonal += c_A diag(K)``. Stores ``R`` and ``A h sigma+`` per point for
    :func:`tri_matvec`."""
    e = wp.tid()
    t = tri_indices[e]
    X = gather(particle_q, t)
    V = gather(particle_qd, t)
    identity = wp.identity(2, float)
    for g in range(3):
        dN = shape_gradients(gauss_point(g))
        Jinv = tri_poses[e, g]
        c = tri_stiffness[e, g]
        F = reference_gradient(X, dN) * Jinv
        R = polar_rotation(F)
        RT = wp.transpose(R)
        T = tensile_part(hooke(RT * F - identity, c[0], c[1]))  # A h sigma+
        tri_rotation[e, g] = R
        tri_tension[e, g] = T
        Fv = reference_gradient(V, dN) * Jinv
        P = R * hooke(RT * (F + velocity_scale * Fv) - identity, c[0], c[1]) + velocity_scale * (Fv * T)
        JinvT = wp.transpose(Jinv)
        scatter(t, -P * JinvT, dN, particle_f)
        # diagonal 3x3 block of node a: R (mu |r|^2 I + (mu + lambda*) r r^T) R^T + (r . T r) I
        for a in range(6):
            r = JinvT * dN[a]
            Rr = R * r
            rr = wp.dot(r, r)
            RRt = wp.vec3(R[0, 0] * R[0, 0] + R[0, 1] * R[0, 1], R[1, 0] * R[1, 0] + R[1, 1] * R[1, 1],
                          R[2, 0] * R[2, 0] + R[2, 1] * R[2, 1])
            block = (c[0] * rr) * RRt + (c[0] + c[1]) * wp.cw_mul(Rr, Rr) + wp.dot(r, T * r) * wp.vec3(1.0)
            wp.atomic_add(particle_diagonal, t[a], matrix_scale * block)


@wp.kernel
def tri_matvec(
    tri_indices: wp.array(dtype=vec6i),
    tri_poses: wp.array2d(dtype=wp.mat22),
    tri_stiffness: wp.array2d(dtype=wp.vec2),
    tri_rotation: wp.array2d(dtype=mat32),
    tri_tension: wp.array2d(dtype=wp.mat22),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """y += scale K x (corotated membrane plus geometric stiffness), matrix-free, with the
    rotations and tension of the last :func:`tri_forces`."""
    e = wp.tid()
    t = tri_indices[e]
    X = gather(x, t)
    for g in range(3):
        dN = shape_gradients(gauss_point(g))
        Jinv = tri_poses[e, g]
        c = scale * tri_stiffness[e, g]
        R = tri_rotation[e, g]
        F = reference_gradient(X, dN) * Jinv
        P = R * hooke(wp.transpose(R) * F, c[0], c[1]) + scale * (F * tri_tension[e, g])
        scatter(t, P * wp.transpose(Jinv), dN, y)


@wp.kernel
def tri_stress(
    tri_indices: wp.array(dtype=vec6i),
    tri_poses: wp.array2d(dtype=wp.mat22),
    tri_lame: wp.array(dtype=wp.vec2),
    particle_q: wp.array(dtype=wp.vec3),
    tri_gauss_stress: wp.array2d(dtype=wp.mat33),
):
    """Corotated plane Cauchy stress (Pa) at the Gauss points, in world axes: ``R sigma R^T``
    (3x3, zero along the element's normal). ``tri_lame`` holds ``(mu, lambda*)`` (Pa)."""
    e = wp.tid()
    t = tri_indices[e]
    X = gather(particle_q, t)
    c = tri_lame[e]
    for g in range(3):
        F = reference_gradient(X, shape_gradients(gauss_point(g))) * tri_poses[e, g]
        R = polar_rotation(F)
        s = hooke(wp.transpose(R) * F - wp.identity(2, float), c[0], c[1])
        tri_gauss_stress[e, g] = R * s * wp.transpose(R)
