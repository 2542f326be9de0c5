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
"""

import warp as wp

from .rotation import polar_rotation


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


@wp.kernel
def tet_forces(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_poses: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    dv_start: wp.array(dtype=wp.vec3),
    tet_rotation_in: wp.array(dtype=wp.quat),
    velocity_scale: float,
    matrix_scale: float,
    rotation_iterations: int,
    rotation_tolerance: float,
    tet_rotation_out: wp.array(dtype=wp.quat),
    tet_rotated_gradients: wp.array(dtype=wp.mat33),
    particle_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
    product_start: wp.array(dtype=wp.vec3),
):
    """Per element, once per step: rotation, rotated gradients and every stiffness term.

    Scatters (with ``c_v = velocity_scale``, ``c_A = matrix_scale``):

    - ``particle_f += -R K (R^T x - X) - c_v R K R^T v``: the corotational internal force
      (eq. 3.49) and the stiffness part of the implicit right-hand side and of Rayleigh
      damping (eq. 3.52, 3.69);
    - ``particle_diagonal += c_A diag(R K R^T)`` (Jacobi preconditioner);
    - ``product_start += c_A R K R^T dv_start``: the stiffness part of ``A dv0`` for the
      warm-started conjugate gradient, so it needs no separate product.

    Hooke's law is isotropic and linear, so ``R sigma(R^T F - I) R^T = sigma(F R^T - I)``
    and all three stress terms combine into one ``sigma((Ds + c_v Dv) g - I)``, where
    ``g = Dm^{-1} R^T`` holds the rotated gradients and ``F R^T = Ds g``.
    """
    e = wp.tid()
    t = tet_indices[e]
    x3 = particle_q[t[3]]
    Ds = wp.matrix_from_cols(particle_q[t[0]] - x3, particle_q[t[1]] - x3, particle_q[t[2]] - x3)
    Dm_inv = tet_poses[e]
    q = polar_rotation(Ds * Dm_inv, tet_rotation_in[e], rotation_iterations, rotation_tolerance)
    tet_rotation_out[e] = q
    g = Dm_inv * wp.transpose(wp.quat_to_matrix(q))  # row l: (R grad N_l)^T
    tet_rotated_gradients[e] = g
    gT = wp.transpose(g)
    c = tet_stiffness[e]

    v3 = particle_qd[t[3]]
    Dv = wp.matrix_from_cols(particle_qd[t[0]] - v3, particle_qd[t[1]] - v3, particle_qd[t[2]] - v3)
    F = -hooke((Ds + velocity_scale * Dv) * g - wp.identity(3, float), c[0], c[1]) * gT
    scatter_columns(t, F, particle_f)

    d3 = dv_start[t[3]]
    Dx = wp.matrix_from_cols(dv_start[t[0]] - d3, dv_start[t[1]] - d3, dv_start[t[2]] - d3)
    scatter_columns(t, hooke(Dx * g, matrix_scale * c[0], matrix_scale * c[1]) * gT, product_start)

    # diagonal of the 3x3 block K_ll = mu |g_l|^2 I + (mu + lambda) g_l g_l^T
    a = c[0] * matrix_scale
    b = (c[0] + c[1]) * matrix_scale
    g3 = -(g[0] + g[1] + g[2])
    wp.atomic_add(particle_diagonal, t[0], a * wp.dot(g[0], g[0]) * wp.vec3(1.0) + b * wp.cw_mul(g[0], g[0]))
    wp.atomic_add(particle_diagonal, t[1], a * wp.dot(g[1], g[1]) * wp.vec3(1.0) + b * wp.cw_mul(g[1], g[1]))
    wp.atomic_add(particle_diagonal, t[2], a * wp.dot(g[2], g[2]) * wp.vec3(1.0) + b * wp.cw_mul(g[2], g[2]))
    wp.atomic_add(particle_diagonal, t[3], a * wp.dot(g3, g3) * wp.vec3(1.0) + b * wp.cw_mul(g3, g3))


@wp.kernel
def tet_matvec(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rotated_gradients: wp.array(dtype=wp.mat33),
    tet_stiffness: wp.array(dtype=wp.vec2),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    k: int,
    rz: wp.array(dtype=float),
    threshold: wp.array(dtype=float),
    y: wp.array(dtype=wp.vec3),
):
    """y += scale R K R^T x, matrix-free.

    Uses the rotated gradients of the last :func:`tet_forces`. Returns at once when
    ``rz[k] <= threshold[0]`` (a converged conjugate gradient keeps its launches, which then
    cost almost nothing, so no host synchronisation is needed).
    """
    if rz[k] <= threshold[0]:
        return
    e = wp.tid()
    t = tet_indices[e]
    g = tet_rotated_gradients[e]
    c = scale * tet_stiffness[e]
    x3 = x[t[3]]
    G = wp.matrix_from_cols(x[t[0]] - x3, x[t[1]] - x3, x[t[2]] - x3) * g
    scatter_columns(t, hooke(G, c[0], c[1]) * wp.transpose(g), y)


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
