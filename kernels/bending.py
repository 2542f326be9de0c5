"""Bending of thin shells: a quadratic hinge energy on the edges of a triangle surface.

The bending model of Bergou, Wardetzky, Harmon, Zorin and Grinspun, "A quadratic bending
model for inextensible surfaces" (SGP 2006), made corotational for a curved rest shape. A
hinge is an edge ``(x0, x1)`` with the opposite vertices ``x2, x3`` of its two triangles; its
weights ``w`` (1/m) are the affine dependency of the four rest points (``sum w = 0``,
``sum w_i X_i = 0`` once the rest shape is flattened), scaled so that ``n . sum w_i x_i`` is the
linearised dihedral angle (rad). The energy is

    E = 1/2 sum_hinges k |sum_i w_i x_i - R_h b|^2,   k = D |e|^2 / (A0 + A1)   (N*m)

with ``D = Y h^3 / (12 (1 - nu^2))`` the flexural rigidity: a discretisation of the plate
energy ``D/2 int (k1 + k2)^2 dA`` (its Gaussian-curvature part, a boundary term, left out),
calibrated so that a sheet bent into a cylinder about a mesh line has that energy (measured
0.984 of it on a 32x32 sheet, the rest lost at the free boundary). Like every hinge energy it
depends on the mesh's directions: on the structured sheets of ``wcut.mesh`` a cylinder bent at
45 degrees to the mesh lines stores 1.74 times the plate energy (``tests/test_bending.py``). ``b`` is
the rest value of ``sum w_i X_i`` (zero for a flat rest shape), stored in the hinge's rest
frame and carried by ``R_h``, the rotation of the frame (edge, normal of triangle
``(x0, x1, x2)``) from rest to now. For a flat rest shape ``R_h b = 0`` and the energy's Hessian
``k w w^T (x) I`` is constant and exact; for a curved one the solver's matrix leaves out the
derivative of ``R_h``, as the corotational elements do.

That matrix is the one of an attachment spring on the weighted point ``sum w_i x_i``, so the
conjugate gradient applies it with ``wcut.kernels.attachments.attachment_matvec``.
"""

import warp as wp


@wp.func
def hinge_frame(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3):
    """Orthonormal frame (edge direction, normal of triangle (x0, x1, x2), their cross) as columns."""
    e = wp.normalize(x1 - x0)
    n = wp.normalize(wp.cross(x1 - x0, x2 - x0))
    return wp.matrix_from_cols(e, n, wp.cross(e, n))


@wp.kernel
def hinge_forces(
    edge_indices: wp.array(dtype=wp.vec4i),
    edge_weights: wp.array(dtype=wp.vec4),
    edge_stiffness: wp.array(dtype=float),
    edge_rest_curvature: wp.array(dtype=wp.vec3),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    velocity_scale: float,
    matrix_scale: float,
    particle_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
):
    """Per hinge: ``particle_f += -k w (w.(x + c_v v) - R_h b)`` and ``particle_diagonal +=
    c_A k w_i^2`` (the terms of ``tet_p1.tet_forces``)."""
    h = wp.tid()
    i = edge_indices[h]
    w = edge_weights[h]
    k = edge_stiffness[h]
    x0 = particle_q[i[0]]
    x1 = particle_q[i[1]]
    x2 = particle_q[i[2]]
    x3 = particle_q[i[3]]
    target = hinge_frame(x0, x1, x2) * edge_rest_curvature[h]
    # sum w = 0: measured from x0, so a body far from the origin loses no float32 digits
    s = w[1] * (x1 - x0) + w[2] * (x2 - x0) + w[3] * (x3 - x0) - target
    s = s + velocity_scale * (w[0] * particle_qd[i[0]] + w[1] * particle_qd[i[1]] + w[2] * particle_qd[i[2]]
                              + w[3] * particle_qd[i[3]])
    for a in range(4):
        wp.atomic_add(particle_f, i[a], (-k * w[a]) * s)
        wp.atomic_add(particle_diagonal, i[a], wp.vec3(matrix_scale * k * w[a] * w[a]))
