"""Corotational quadratic tetrahedra (P2, 10 nodes): forces, system-matrix product, stress.

Node order is VTK tetra10 (``wcut.p2``): corners 0..3, then the nodes of edges (0,1), (1,2),
(2,0), (0,3), (1,3), (2,3). Reference coordinates are ``xi = (L1, L2, L3)``. Per element and
Gauss point ``g`` (the 4-point rule of degree 2, one point near each corner; exact for the
stiffness of a straight element):

- ``tet_poses[e, g] = J^{-1}``, the inverse of the rest Jacobian ``J = dX/dxi`` (1/m), so a
  curved (isoparametric) rest element is handled exactly like a straight one;
- ``tet_stiffness[e, g] = w_g det J (mu, lambda)`` (N*m): the Gauss point's share of the rest
  volume times the Lame parameters.

At a Gauss point ``F = (dx/dxi) J^{-1}``, as ``F = Ds Dm^{-1}`` for P1 (``wcut.kernels.tet_p1``).

Rotation: one rotation per Gauss point, the polar rotation of that point's ``F``, warm-started
from the last step. A quadratic element represents bending inside itself (a single element
of a coarse beam curls), so its deformation gradient, and its rotation, vary across it; one
rotation per element (e.g. of ``F`` at the centroid) would leave the rotation's variation
inside the element as spurious strain, stiffening bending under large rotations. Per Gauss
point the corotational stress is exactly zero for any rigid motion of a curved element and
each point's strain is measured in its own frame; the cost is four polar decompositions per
element instead of one, warm-started so each takes one or two Newton iterations.

Force on node ``a``: ``f_a = -sum_g w_g det J_g R_g sigma(R_g^T F_g - I) grad_X N_a(xi_g)``
(thesis eq. 3.48-3.49 integrated by quadrature), and the stiffness product uses, as for P1,
the rotated gradients ``g = J^{-1} R^T`` stored once per step, and the rotation stiffness of
each Gauss point (``wcut.kernels.rotation.rotation_stiffness``) for the tangent ``K_t``.

Compilation: on the CPU this module is compiled with reassociation, reciprocals and fused
multiply-adds allowed (``FAST_ARITHMETIC_FLAGS``), which let LLVM regroup the short sums of
these dense per-element kernels: forces and product about 10 % faster (measured side by side
on the 10k-element beam of ``wcut bench``). The results differ from strict IEEE order by
rounding only; NaN and infinity keep their meaning (no ``-ffast-math``: the solver's
non-finite check relies on them).
"""

import warp as wp

from .rotation import axial, polar_rotation, rotation_stiffness
from .tet_p1 import hooke, rotation_stiffness_diagonal, tangent_stress

#: clang (cc1) flags added for this module on the CPU, after Warp's own
FAST_ARITHMETIC_FLAGS = "-mreassociate -freciprocal-math -fno-signed-zeros -ffp-contract=fast"
wp.set_module_options(
    {"cpu_compiler_flags": f"{wp.config.cpu_compiler_flags or '-march=native'} {FAST_ARITHMETIC_FLAGS}"})

vec10i = wp.types.vector(length=10, dtype=wp.int32)
mat10x3 = wp.types.matrix(shape=(10, 3), dtype=float)

#: The 4-point rule: Gauss point g has barycentric coordinate GAUSS_A at corner g, GAUSS_B elsewhere.
GAUSS_A = wp.constant(0.5854101966249685)
GAUSS_B = wp.constant(0.1381966011250105)


@wp.func
def gauss_point(g: int):
    """Barycentric coordinates (L0, L1, L2, L3) of Gauss point g."""
    L = wp.vec4(GAUSS_B)
    L[g] = GAUSS_A
    return L


#: The gradient along L_k at a Gauss point, split into a part common to all four points and
#: one node per point: ``dx/dL_k(L_g) = base_k + GAUSS_C x_{T[k][g]}`` with
#: ``base_k = GAUSS_B S_k - (GAUSS_A - GAUSS_B) x_k``, ``S_k = 4 sum_{m != k} x_km`` and
#: ``T[k][g]`` the node of edge (k, g), or corner k when g = k (since a + 3b = 1). Sharing
#: ``base`` between the points, and its transpose in :func:`finish_nodal`, halves the work of
#: the stiffness product (sum factorisation).
GAUSS_C = wp.constant(4.0 * (0.5854101966249685 - 0.1381966011250105))
mat14x3 = wp.types.matrix(shape=(14, 3), dtype=float)
mat43 = wp.types.matrix(shape=(4, 3), dtype=float)


@wp.func
def node_of(k: int, g: int):
    """T[k][g]: corner k if g == k, else the node of edge (k, g) (VTK tetra10 numbering)."""
    lo = wp.min(k, g)
    hi = wp.max(k, g)
    if lo == hi:
        return lo
    if lo == 0:
        if hi == 1:
            return 4
        if hi == 2:
            return 6
        return 7
    if lo == 1:
        if hi == 2:
            return 5
        return 8
    return 9


@wp.func
def gradient_bases(X: mat10x3):
    """Rows base_k (k = 0..3), the part of dx/dL_k shared by the four Gauss points."""
    d = GAUSS_A - GAUSS_B
    B = mat43()
    B[0] = (4.0 * GAUSS_B) * (X[4] + X[6] + X[7]) - d * X[0]
    B[1] = (4.0 * GAUSS_B) * (X[4] + X[5] + X[8]) - d * X[1]
    B[2] = (4.0 * GAUSS_B) * (X[5] + X[6] + X[9]) - d * X[2]
    B[3] = (4.0 * GAUSS_B) * (X[7] + X[8] + X[9]) - d * X[3]
    return B


@wp.func
def gauss_gradient(X: mat10x3, B: mat43, g: int):
    """``dx/dxi`` (3x3) at Gauss point g from the nodal field X and its bases B: columns
    ``dx/dL_k - dx/dL_0``, k = 1..3, where ``dx/dL_k = (4 L_k - 1) x_k + 4 sum_j L_j x_kj``."""
    p0 = B[0] + GAUSS_C * X[node_of(0, g)]
    return wp.matrix_from_cols(B[1] + GAUSS_C * X[node_of(1, g)] - p0, B[2] + GAUSS_C * X[node_of(2, g)] - p0,
                               B[3] + GAUSS_C * X[node_of(3, g)] - p0)


@wp.func
def add_gauss_nodal(acc: mat14x3, Q: wp.mat33, g: int):
    """Accumulate the transpose of :func:`gauss_gradient` applied to Q (whose columns are
    conjugate to xi): rows 0..9 gather the per-point part, rows 10..13 the sums D_k of the
    L-space vectors ``d_k`` that :func:`finish_nodal` spreads."""
    c1 = wp.vec3(Q[0, 0], Q[1, 0], Q[2, 0])
    c2 = wp.vec3(Q[0, 1], Q[1, 1], Q[2, 1])
    c3 = wp.vec3(Q[0, 2], Q[1, 2], Q[2, 2])
    c0 = -(c1 + c2 + c3)
    a0 = node_of(0, g)
    a1 = node_of(1, g)
    a2 = node_of(2, g)
    a3 = node_of(3, g)
    acc[a0] = acc[a0] + GAUSS_C * c0
    acc[a1] = acc[a1] + GAUSS_C * c1
    acc[a2] = acc[a2] + GAUSS_C * c2
    acc[a3] = acc[a3] + GAUSS_C * c3
    acc[10] = acc[10] + c0
    acc[11] = acc[11] + c1
    acc[12] = acc[12] + c2
    acc[13] = acc[13] + c3
    return acc


@wp.func
def finish_nodal(acc: mat14x3):
    """The ten nodal vectors of an accumulation by :func:`add_gauss_nodal`: corner k gets
    ``-(a - b) D_k``, the node of edge (i, j) gets ``4 b (D_i + D_j)``."""
    d = GAUSS_A - GAUSS_B
    f = mat10x3()
    for a in range(10):
        f[a] = acc[a]
    f[0] = f[0] - d * acc[10]
    f[1] = f[1] - d * acc[11]
    f[2] = f[2] - d * acc[12]
    f[3] = f[3] - d * acc[13]
    e = 4.0 * GAUSS_B
    f[4] = f[4] + e * (acc[10] + acc[11])
    f[5] = f[5] + e * (acc[11] + acc[12])
    f[6] = f[6] + e * (acc[12] + acc[10])
    f[7] = f[7] + e * (acc[10] + acc[13])
    f[8] = f[8] + e * (acc[11] + acc[13])
    f[9] = f[9] + e * (acc[12] + acc[13])
    return f


@wp.func
def gather(x: wp.array(dtype=wp.vec3), t: vec10i):
    """The ten nodal vectors of an element, as rows."""
    X = mat10x3()
    for a in range(10):
        X[a] = x[t[a]]
    return X


@wp.func
def nodal_vectors(Q: wp.mat33, L: wp.vec4):
    """Row a: ``sum_i dN_a/dxi_i Q[:, i]`` at barycentric point L; with ``Q = g^T`` the
    rotated shape-function gradients ``R grad N_a`` (their squares make the diagonal)."""
    c1 = wp.vec3(Q[0, 0], Q[1, 0], Q[2, 0])
    c2 = wp.vec3(Q[0, 1], Q[1, 1], Q[2, 1])
    c3 = wp.vec3(Q[0, 2], Q[1, 2], Q[2, 2])
    c0 = -(c1 + c2 + c3)
    N = mat10x3()
    N[0] = (4.0 * L[0] - 1.0) * c0
    N[1] = (4.0 * L[1] - 1.0) * c1
    N[2] = (4.0 * L[2] - 1.0) * c2
    N[3] = (4.0 * L[3] - 1.0) * c3
    N[4] = 4.0 * (L[1] * c0 + L[0] * c1)
    N[5] = 4.0 * (L[2] * c1 + L[1] * c2)
    N[6] = 4.0 * (L[0] * c2 + L[2] * c0)
    N[7] = 4.0 * (L[3] * c0 + L[0] * c3)
    N[8] = 4.0 * (L[3] * c1 + L[1] * c3)
    N[9] = 4.0 * (L[3] * c2 + L[2] * c3)
    return N


@wp.func
def scatter(t: vec10i, f: mat10x3, y: wp.array(dtype=wp.vec3)):
    for a in range(10):
        wp.atomic_add(y, t[a], f[a])


@wp.kernel
def tet_forces(
    tet_indices: wp.array(dtype=vec10i),
    tet_poses: wp.array2d(dtype=wp.mat33),
    tet_stiffness: wp.array2d(dtype=wp.vec2),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    tet_rotation_in: wp.array2d(dtype=wp.quat),
    velocity_scale: float,
    matrix_scale: float,
    rotation_iterations: int,
    rotation_tolerance: float,
    with_rotation_stiffness: int,
    tet_rotation_out: wp.array2d(dtype=wp.quat),
    tet_rotated_gradients: wp.array2d(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array2d(dtype=wp.mat33),
    particle_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
):
    """Per element, once per step: rotations, rotated gradients and rotation stiffness at the
    Gauss points, and the same three terms as ``tet_p1.tet_forces`` with the tangent stiffness
    ``K_t``: ``particle_f += -R K (R^T x - X) - c_v K_t v`` and ``particle_diagonal += c_A
    diag(K_t)``."""
    e = wp.tid()
    t = tet_indices[e]
    X = gather(particle_q, t)
    W = X + velocity_scale * gather(particle_qd, t)  # strain and damping in one stress
    BX = gradient_bases(X)
    BW = gradient_bases(W)
    force = mat14x3()
    diagonal = mat10x3()
    for g in range(4):
        Jinv = tet_poses[e, g]
        Ds = gauss_gradient(X, BX, g)
        q = polar_rotation(Ds * Jinv, tet_rotation_in[e, g], rotation_iterations, rotation_tolerance)
        tet_rotation_out[e, g] = q
        gm = Jinv * wp.transpose(wp.quat_to_matrix(q))
        tet_rotated_gradients[e, g] = gm
        gT = wp.transpose(gm)
        c = tet_stiffness[e, g]
        V = Ds * gm  # F R^T
        Ks = wp.mat33(0.0)
        if with_rotation_stiffness != 0:
            Ks = rotation_stiffness(V, c[0], c[1])
        tet_rotation_stiffness[e, g] = Ks
        HW = gauss_gradient(W, BW, g) * gm  # V + c_v (velocity gradient) R^T
        stress = hooke(HW - wp.identity(3, float), c[0], c[1]) + wp.skew(Ks * axial(HW - V))
        force = add_gauss_nodal(force, -stress * gT, g)
        # diagonal 3x3 block of node a: mu |r_a|^2 I + (mu + lambda) r_a r_a^T, r_a = R grad N_a
        r = nodal_vectors(gT, gauss_point(g))
        a_coef = matrix_scale * c[0]
        b_coef = matrix_scale * (c[0] + c[1])
        for a in range(10):
            ra = r[a]
            diagonal[a] = (diagonal[a] + a_coef * wp.dot(ra, ra) * wp.vec3(1.0) + b_coef * wp.cw_mul(ra, ra)
                           + matrix_scale * rotation_stiffness_diagonal(Ks, ra))
    scatter(t, finish_nodal(force), particle_f)
    scatter(t, diagonal, particle_diagonal)


@wp.func
def element_matvec(
    e: int,
    tet_indices: wp.array(dtype=vec10i),
    tet_rotated_gradients: wp.array2d(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array2d(dtype=wp.mat33),
    tet_stiffness: wp.array2d(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """Element e's share of ``y += scale K_t x`` (see :func:`tet_matvec`)."""
    t = tet_indices[e]
    X = gather(x, t)
    B = gradient_bases(X)
    acc = mat14x3()
    for g in range(4):
        gm = tet_rotated_gradients[e, g]
        c = tet_stiffness[e, g]
        stress = tangent_stress(gauss_gradient(X, B, g) * gm, c[0], c[1], tet_rotation_stiffness[e, g], scale)
        acc = add_gauss_nodal(acc, stress * wp.transpose(gm), g)
    scatter(t, finish_nodal(acc), y)


@wp.kernel
def tet_matvec(
    tet_indices: wp.array(dtype=vec10i),
    tet_rotated_gradients: wp.array2d(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array2d(dtype=wp.mat33),
    tet_stiffness: wp.array2d(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """y += scale K_t x, matrix-free, with the rotated gradients and rotation stiffness of the
    last :func:`tet_forces`."""
    element_matvec(wp.tid(), tet_indices, tet_rotated_gradients, tet_rotation_stiffness, tet_stiffness, x, scale, y)


@wp.kernel
def tet_matvec_listed(
    elements: wp.array(dtype=wp.int32),
    tet_indices: wp.array(dtype=vec10i),
    tet_rotated_gradients: wp.array2d(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array2d(dtype=wp.mat33),
    tet_stiffness: wp.array2d(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """:func:`tet_matvec` over the listed elements only (one thread each)."""
    element_matvec(elements[wp.tid()], tet_indices, tet_rotated_gradients, tet_rotation_stiffness, tet_stiffness, x,
                   scale, y)


@wp.kernel
def tet_stress(
    tet_indices: wp.array(dtype=vec10i),
    tet_poses: wp.array2d(dtype=wp.mat33),
    tet_stiffness: wp.array2d(dtype=wp.vec2),
    tet_rotation: wp.array2d(dtype=wp.quat),
    particle_q: wp.array(dtype=wp.vec3),
    tet_cauchy_stress: wp.array(dtype=wp.mat33),
    tet_von_mises: wp.array(dtype=float),
):
    """Corotated linear stress (Pa) in world axes, averaged over the element's Gauss points
    (weighted by their volume shares), and the von Mises value of that average."""
    e = wp.tid()
    t = tet_indices[e]
    X = gather(particle_q, t)
    B = gradient_bases(X)
    total = wp.mat33()
    volume = float(0.0)
    for g in range(4):
        R = wp.quat_to_matrix(tet_rotation[e, g])
        c = tet_stiffness[e, g]  # V_g (mu, lambda): the sum is of V_g sigma_g
        F = gauss_gradient(X, B, g) * tet_poses[e, g]
        total = total + R * hooke(wp.transpose(R) * F - wp.identity(3, float), c[0], c[1]) * wp.transpose(R)
        volume = volume + 1.0 / (24.0 * wp.determinant(tet_poses[e, g]))  # V_g = w_g det J
    s = total * (1.0 / volume)
    tet_cauchy_stress[e] = s
    d = s - (wp.trace(s) / 3.0) * wp.identity(3, float)
    tet_von_mises[e] = wp.sqrt(1.5 * wp.ddot(d, d))
