"""Node-wise kernels of the implicit Euler step (thesis eq. 3.59-3.61 and 3.69).

With ``h = dt``, Rayleigh damping ``D = alpha M + beta K`` (eq. 3.52) and the lumped mass
``M``, one Newton step solves ``A dv = b`` for the velocity change:

    A = (1 + h alpha) M + (h^2 + h beta) K + h^2 K_attach
    b = h (f_int + f_ext + M g + f_attach - alpha M v) - (h^2 + h beta) K v - h^2 K_attach v

(eq. 3.69 with ``dv = h a``). The element and attachment kernels scatter the force terms into
``particle_f`` and the stiffness diagonals into ``particle_diagonal``; the kernels here add
the nodal terms. Fixed (Dirichlet) vertices get ``b = 0`` and a zero preconditioner, so the
conjugate gradient never moves them.
"""

import warp as wp


@wp.kernel
def assemble_system(
    particle_mass: wp.array(dtype=float),
    particle_load_mass: wp.array(dtype=float),
    particle_fixed: wp.array(dtype=wp.int32),
    particle_qd: wp.array(dtype=wp.vec3),
    particle_f: wp.array(dtype=wp.vec3),
    external_f: wp.array(dtype=wp.vec3),
    particle_diagonal: wp.array(dtype=wp.vec3),
    gravity: wp.vec3,
    dt: float,
    rayleigh_mass: float,
    rhs: wp.array(dtype=wp.vec3),
    inv_diagonal: wp.array(dtype=wp.vec3),
    mass_scale: wp.array(dtype=float),
    load_acceleration: wp.array(dtype=float),
):
    """Right-hand side ``b``, inverse diagonal of ``A`` (Jacobi) and ``(1 + h alpha) m``, and
    ``load_acceleration[0] = max |f_ext| / m`` (m/s^2, for the divergence check).

    Gravity acts through ``particle_load_mass`` (the consistent load ``int rho N_i dV``), inertia
    and damping through the lumped ``particle_mass``; they are equal for linear elements."""
    i = wp.tid()
    if particle_fixed[i] != 0:
        rhs[i] = wp.vec3(0.0)
        inv_diagonal[i] = wp.vec3(0.0)
        return
    m = particle_mass[i]
    f = external_f[i]
    if f[0] != 0.0 or f[1] != 0.0 or f[2] != 0.0:
        wp.atomic_max(load_acceleration, 0, wp.length(f) / m)
    rhs[i] = dt * (particle_f[i] + f + particle_load_mass[i] * gravity - (rayleigh_mass * m) * particle_qd[i])
    ms = (1.0 + dt * rayleigh_mass) * m
    mass_scale[i] = ms
    d = particle_diagonal[i] + wp.vec3(ms)
    inv_diagonal[i] = wp.vec3(1.0 / d[0], 1.0 / d[1], 1.0 / d[2])


@wp.kernel
def integrate(
    particle_fixed: wp.array(dtype=wp.int32),
    particle_q: wp.array(dtype=wp.vec3),
    particle_qd: wp.array(dtype=wp.vec3),
    dv: wp.array(dtype=wp.vec3),
    dt: float,
    particle_q_out: wp.array(dtype=wp.vec3),
    particle_qd_out: wp.array(dtype=wp.vec3),
    nonfinite_count: wp.array(dtype=wp.int32),
    speed_sq_max: wp.array(dtype=float),
):
    """v' = v + dv, x' = x + h v' (eq. 3.60-3.61); fixed vertices keep their position.

    Counts the vertices whose new position or velocity is not finite and keeps the largest
    squared speed (m^2/s^2) in ``speed_sq_max[0]``, for the divergence check."""
    i = wp.tid()
    x = particle_q[i]
    if particle_fixed[i] != 0:
        if not wp.isfinite(x):
            wp.atomic_add(nonfinite_count, 0, 1)
        particle_q_out[i] = x
        particle_qd_out[i] = wp.vec3(0.0)
        return
    v = particle_qd[i] + dv[i]
    x = x + dt * v
    if not (wp.isfinite(x) and wp.isfinite(v)):
        wp.atomic_add(nonfinite_count, 0, 1)
    else:
        wp.atomic_max(speed_sq_max, 0, wp.dot(v, v))
    particle_q_out[i] = x
    particle_qd_out[i] = v
