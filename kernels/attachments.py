"""Attachment springs: a vertex or a barycentric point pulled towards a target.

Spring ``s`` joins the point ``p_s = sum_j w_sj x_j`` (up to four vertices, unused slots have
weight 0) to ``target_s`` with stiffness ``k_s`` (N/m): energy ``k_s |p_s - target_s|^2 / 2``.
Its stiffness matrix is ``k_s (w_s w_s^T)`` times the 3x3 identity. Attachments are treated
implicitly, like the elements, so stiff grabbing springs stay stable.
"""

import warp as wp


@wp.kernel
def attachment_forces(
    attachment_indices: wp.array(dtype=wp.vec4i),
    attachment_weights: wp.array(dtype=wp.vec4),
    attachment_stiffness: wp.array(dtype=float),
    attachment_target: wp.array(dtype=wp.vec3),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    velocity_scale: float,
    matrix_scale: float,
    particle_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
    reach_max: wp.array(dtype=float),
):
    """Spring terms of one step, mirroring :func:`wcut.kernels.tet_p1.tet_forces`.

    Scatters the force ``-k w_j (p - target + velocity_scale dp/dt)`` and the diagonal
    ``matrix_scale k w_j^2``; keeps the largest distance ``|p - target|`` (m) in
    ``reach_max[0]`` (for the divergence check: a spring can pull its point at that distance
    per step).
    """
    s = wp.tid()
    idx = attachment_indices[s]
    w = attachment_weights[s]
    k = attachment_stiffness[s]
    p = wp.vec3(0.0)
    pd = wp.vec3(0.0)
    for j in range(4):
        p += w[j] * particle_q[idx[j]]
        pd += w[j] * particle_qd[idx[j]]
    gap = p - attachment_target[s]
    if k > 0.0:
        wp.atomic_max(reach_max, 0, wp.length(gap))
    f = -k * (gap + velocity_scale * pd)
    for j in range(4):
        if w[j] != 0.0:
            wp.atomic_add(particle_f, idx[j], w[j] * f)
            wp.atomic_add(particle_diagonal, idx[j], wp.vec3(matrix_scale * k * w[j] * w[j]))


@wp.kernel
def attachment_matvec(
    attachment_indices: wp.array(dtype=wp.vec4i),
    attachment_weights: wp.array(dtype=wp.vec4),
    attachment_stiffness: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    scale: float,
    y: wp.array(dtype=wp.vec3),
):
    """y += scale K_attach x."""
    s = wp.tid()
    idx = attachment_indices[s]
    w = attachment_weights[s]
    p = wp.vec3(0.0)
    for j in range(4):
        p += w[j] * x[idx[j]]
    kp = (scale * attachment_stiffness[s]) * p
    for j in range(4):
        if w[j] != 0.0:
            wp.atomic_add(y, idx[j], w[j] * kp)
