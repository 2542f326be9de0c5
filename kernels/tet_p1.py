"""Corotational linear tetrahedra (P1): forces, system-matrix product, stress.

Notation (thesis 3.2): node 3 of each element is the local origin; ``tet_poses``
holds ``Dm^{-1}`` with ``Dm = [X0-X3 | X1-X3 | X2-X3]``, so its row ``l`` is the constant
shape-function gradient ``grad N_l`` (l = 0, 1, 2; ``grad N_3 = -sum``), in 1/m.
``tet_stiffness`` holds ``(V mu, V lambda)`` in N*m: rest volume times the Lame parameters.

The element stiffness of eq. 3.48 applied to nodal vectors ``u_l`` is
``(K u)_l = V sigma(G) grad N_l`` with ``G = sum_l u_l grad N_l^T`` and Hooke's law
``sigma(G) = mu (G + G^T) + lambda tr(G) I``. Hooke's law is isotropic, so the corotated
stiffness of eq. 3.49 needs no 12x12 matrix: ``R K R^T u`` is the same expression with the
rotated gradients ``g_l = R grad N_l``. :func:`tet_forces` stores those rotated gradients
once per step and :func:`tet_matvec` reuses them in every conjugate-gradient iteration.

The system matrix uses the tangent ``K_t = R K R^T + K_G``: ``K_G`` is the stiffness of the
rotation's variation (:func:`wcut.kernels.rotation.rotation_stiffness`, a symmetric 3x3 ``G``
per element, projected to its tension part), whose stress for a rotated displacement gradient
H is ``[G axial(H)]_x``. It adds ~20 flops per element to the product and makes the transverse
stiffness of stretched elements implicit. With ``G = 0`` the matrix is the thesis's R K R^T.
"""

import warp as wp

from .rotation import axial, polar_rotation, rotation_stiffness


@wp.func
def hooke(G: wp.mat33, mu: float, lam: float):
    """Linear isotropic stress of a displacement gradient G (sym(G) is the small strain)."""
    return mu * (G + wp.transpose(G)) + (lam * wp.trace(G)) * wp.identity(3, float)


@wp.func
def scatter_columns(t: wp.vec4i, F: wp.mat33, y: wp.array(dtype=wp.vec3)):
    """Add column l of F to node l (l = 0..2) and minus their sum to node 3."""
    f0 = wp.vec3(F[0, 0], F[1, 0], F[2, 0])
    f1 = wp.vec3(F[0, 1], F[1, 1], F[2, 1])
    f2 = wp.vec3(F[0, 2], F[1, 2], F[2, 2])
    wp.atomic_add(y, t[0], f0)
    wp.atomic_add(y, t[1], f1)
    wp.atomic_add(y, t[2], f2)
    wp.atomic_add(y, t[3], -(f0 + f1 + f2))


@wp.func
def rotation_stiffness_diagonal(G: wp.mat33, r: wp.vec3):
    """Diagonal of the 3x3 block ``[r]_x^T G [r]_x / 2`` that the rotation stiffness G
    (:func:`wcut.kernels.rotation.rotation_stiffness`) adds for a node with rotated gradient r."""
    return 0.5 * wp.vec3(G[1, 1] * r[2] * r[2] + G[2, 2] * r[1] * r[1] - 2.0 * G[1, 2] * r[1] * r[2],
                         G[0, 0] * r[2] * r[2] + G[2, 2] * r[0] * r[0] - 2.0 * G[0, 2] * r[0] * r[2],
                         G[0, 0] * r[1] * r[1] + G[1, 1] * r[0] * r[0] - 2.0 * G[0, 1] * r[0] * r[1])


@wp.func
def tangent_stress(H: wp.mat33, mu: float, lam: float, G: wp.mat33, scale: float):
    """``scale (sigma(H) + [G axial(H)]_x)``: the stress of the tangent stiffness (corotated
    Hooke plus rotation stiffness G, which already holds ``V mu`` units) for the rotated
    displacement gradient ``H = Dx Dm^-1 R^T``."""
    return scale * (hooke(H, mu, lam) + wp.skew(G * axial(H)))


@wp.kernel
def tet_forces(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_poses: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    rest_q: wp.array(dtype=wp.vec3),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    tet_rotation_in: wp.array(dtype=wp.quat),
    velocity_scale: float,
    matrix_scale: float,
    rotation_iterations: int,
    rotation_tolerance: float,
    with_rotation_stiffness: int,
    tet_rotation_out: wp.array(dtype=wp.quat),
    tet_rotated_gradients: wp.array(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array(dtype=wp.mat33),
    particle_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
):
    """Per element, once per step: rotation, rotated gradients and every stiffness term.

    Scatters (with ``c_v = velocity_scale``, ``c_A = matrix_scale`` and the tangent stiffness
    ``K_t = R K R^T + K_G``, where ``K_G`` is the rotation stiffness stored in
    ``tet_rotation_stiffness`` when ``with_rotation_stiffness`` is 1, else zero):

    - ``particle_f += -R K (R^T x - X) - c_v K_t v``: the corotational internal force
      (eq. 3.49) and the stiffness part of the implicit right-hand side and of Rayleigh
      damping (eq. 3.52, 3.69);
    - ``particle_diagonal += c_A diag(K_t)`` (the diagonal of the system matrix).

    Hooke's law is isotropic and linear, so ``R sigma(R^T F - I) R^T = sigma(F R^T - I)``, with
    ``g = Dm^{-1} R^T`` holding the rotated gradients. The deformation gradient is taken from
    the displacements ``u = x - X`` (``rest_q`` holds X): ``F = I + Du Dm^{-1}`` and
    ``F R^T - I = R^T - I + Du g``. From positions, ``Ds Dm^{-1}`` cancels terms of the size of
    ``Dm^{-1}``'s entries down to ``I``: on a sliver of aspect 1e4 its float32 rounding is a
    strain of 1e-3 at rest, a force the solver resolves into motion; from displacements the
    rest state is exactly stress-free.
    """
    e = wp.tid()
    t = tet_indices[e]
    u3 = particle_q[t[3]] - rest_q[t[3]]
    Du = wp.matrix_from_cols(particle_q[t[0]] - rest_q[t[0]] - u3, particle_q[t[1]] - rest_q[t[1]] - u3,
                             particle_q[t[2]] - rest_q[t[2]] - u3)
    Dm_inv = tet_poses[e]
    identity = wp.identity(3, float)
    q = polar_rotation(identity + Du * Dm_inv, tet_rotation_in[e], rotation_iterations, rotation_tolerance)
    tet_rotation_out[e] = q
    RT = wp.transpose(wp.quat_to_matrix(q))
    g = Dm_inv * RT  # row l: (R grad N_l)^T
    tet_rotated_gradients[e] = g
    gT = wp.transpose(g)
    c = tet_stiffness[e]

    Ks = wp.mat33(0.0)
    if with_rotation_stiffness != 0:
        Ks = rotation_stiffness(RT + Du * g, c[0], c[1])
    tet_rotation_stiffness[e] = Ks

    v3 = particle_qd[t[3]]
    Dv = wp.matrix_from_cols(particle_qd[t[0]] - v3, particle_qd[t[1]] - v3, particle_qd[t[2]] - v3)
    # strain and damping in one Hooke stress, as in the thesis's form: computed apart, their
    # float32 rounding lets a thin element far from the origin creep instead of resting
    stress = hooke(RT - identity + (Du + velocity_scale * Dv) * g, c[0], c[1])
    stress = stress + velocity_scale * wp.skew(Ks * axial(Dv * g))
    scatter_columns(t, -stress * gT, particle_f)

    # diagonal of the 3x3 block K_ll = mu |g_l|^2 I + (mu + lambda) g_l g_l^T, plus K_G's
    a = c[0] * matrix_scale
    b = (c[0] + c[1]) * matrix_scale
    g3 = -(g[0] + g[1] + g[2])
    for l in range(4):
        r = g3
        if l < 3:
            r = g[l]
        wp.atomic_add(particle_diagonal, t[l], a * wp.dot(r, r) * wp.vec3(1.0) + b * wp.cw_mul(r, r)
                      + matrix_scale * rotation_stiffness_diagonal(Ks, r))


@wp.func
def element_matvec(
    e: int,
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rotated_gradients: wp.array(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """Element e's share of ``y += scale K_t x`` (see :func:`tet_matvec`)."""
    t = tet_indices[e]
    g = tet_rotated_gradients[e]
    c = tet_stiffness[e]
    x3 = x[t[3]]
    H = wp.matrix_from_cols(x[t[0]] - x3, x[t[1]] - x3, x[t[2]] - x3) * g
    scatter_columns(t, tangent_stress(H, c[0], c[1], tet_rotation_stiffness[e], scale) * wp.transpose(g), y)


@wp.kernel
def tet_matvec(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rotated_gradients: wp.array(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """y += scale K_t x with the tangent stiffness ``K_t = R K R^T + K_G``, matrix-free.

    Uses the rotated gradients and rotation stiffness of the last :func:`tet_forces`.
    """
    element_matvec(wp.tid(), tet_indices, tet_rotated_gradients, tet_rotation_stiffness, tet_stiffness, x, scale, y)


@wp.kernel
def tet_matvec_listed(
    elements: wp.array(dtype=wp.int32),
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rotated_gradients: wp.array(dtype=wp.mat33),
    tet_rotation_stiffness: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """:func:`tet_matvec` over the listed elements only (one thread each)."""
    element_matvec(elements[wp.tid()], tet_indices, tet_rotated_gradients, tet_rotation_stiffness, tet_stiffness, x,
                   scale, y)


@wp.kernel
def tet_stress(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_poses: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    tet_rest_volume: wp.array(dtype=float),
    tet_rotation: wp.array(dtype=wp.quat),
    particle_q: wp.array(dtype=wp.vec3),
    tet_cauchy_stress: wp.array(dtype=wp.mat33),
    tet_von_mises: wp.array(dtype=float),
):
    """Corotated linear stress (Pa) per element, in world axes, and its von Mises value."""
    e = wp.tid()
    t = tet_indices[e]
    x3 = particle_q[t[3]]
    Ds = wp.matrix_from_cols(particle_q[t[0]] - x3, particle_q[t[1]] - x3, particle_q[t[2]] - x3)
    R = wp.quat_to_matrix(tet_rotation[e])
    c = tet_stiffness[e] / tet_rest_volume[e]
    s = hooke(wp.transpose(R) * Ds * tet_poses[e] - wp.identity(3, float), c[0], c[1])
    tet_cauchy_stress[e] = R * s * wp.transpose(R)
    d = s - (wp.trace(s) / 3.0) * wp.identity(3, float)
    tet_von_mises[e] = wp.sqrt(1.5 * wp.ddot(d, d))
