"""Fused Jacobi-preconditioned conjugate gradient on nodal vec3 arrays.

One iteration is the element (and attachment) products into ``q`` and three node-wise kernels,
each fusing a vector update with the dot product the next one needs:
:func:`cg_apply_mass` (``q = A p``, ``p.q``), :func:`cg_update` (x, r, z, ``r.z``) and
:func:`cg_direction` (p). The scalars live on the device, one slot per iteration
(``rz[k]``, ``pq[k]``), so an iteration never reads back to the host and the whole loop can be
recorded once (CPU) or captured in a graph (CUDA). Convergence is checked on the device: once
``rz[k] <= threshold`` (``threshold = tol^2 * b.D^-1 b``, D the diagonal of A) every later
launch returns at once.
Fixed vertices have a zero preconditioner; their r, z, p stay zero.

(Folding ``p.q`` into the element product, to save :func:`cg_apply_mass`, was measured slower
on the CPU: the per-element add to one address serialises the element loop.)
"""

import warp as wp

from .partial_sums import take_partials


@wp.kernel
def cg_init(
    rhs: wp.array(dtype=wp.vec3),
    inv_diagonal: wp.array(dtype=wp.vec3),
    mass_scale: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    tolerance_sq: float,
    q: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
    norms: wp.array(dtype=float),
):
    """r = b - A x (q holds the stiffness part of A x), z = D^-1 r, p = z, rz[0] = r.z.

    Also sums ``norms[1] = b.D^-1 b`` and the convergence threshold
    ``norms[0] = tolerance_sq * b.D^-1 b``, and clears ``q``.
    """
    i = wp.tid()
    d = inv_diagonal[i]
    zero = wp.vec3(0.0)
    if d[0] == 0.0:  # fixed vertex: outside the system
        x[i] = zero
        r[i] = zero
        z[i] = zero
        p[i] = zero
        q[i] = zero
        return
    b = rhs[i]
    ri = b - (q[i] + mass_scale[i] * x[i])
    zi = wp.cw_mul(d, ri)
    r[i] = ri
    z[i] = zi
    p[i] = zi
    q[i] = zero
    wp.atomic_add(rz, 0, wp.dot(ri, zi))
    bb = wp.dot(b, wp.cw_mul(d, b))
    wp.atomic_add(norms, 0, tolerance_sq * bb)
    wp.atomic_add(norms, 1, bb)


@wp.kernel
def cg_apply_mass(
    k: int,
    inv_diagonal: wp.array(dtype=wp.vec3),
    mass_scale: wp.array(dtype=float),
    p: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
    threshold: wp.array(dtype=float),
    partials: wp.array2d(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    pq: wp.array(dtype=float),
):
    """q = A p (adding the mass term and the rows of ``partials`` to the stiffness part
    already in q, and clearing those rows); pq[k] = p.q.

    ``partials`` holds the scatters of an element product split over CPU threads
    (``wcut.split_launch``); it has no rows otherwise."""
    if rz[k] <= threshold[0]:
        return
    i = wp.tid()
    qi = take_partials(partials, i, q[i])
    if inv_diagonal[i][0] == 0.0:
        q[i] = wp.vec3(0.0)
        return
    qi = qi + mass_scale[i] * p[i]
    q[i] = qi
    wp.atomic_add(pq, k, wp.dot(p[i], qi))


@wp.kernel
def cg_update(
    k: int,
    inv_diagonal: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    pq: wp.array(dtype=float),
    threshold: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
):
    """x += alpha p, r -= alpha q, z = D^-1 r, rz[k+1] = r.z, q = 0 (alpha = rz[k] / pq[k])."""
    i = wp.tid()
    if rz[k] <= threshold[0]:
        if i == 0:
            rz[k + 1] = rz[k]
        return
    alpha = float(0.0)
    if pq[k] > 0.0:
        alpha = rz[k] / pq[k]
    x[i] = x[i] + alpha * p[i]
    ri = r[i] - alpha * q[i]
    zi = wp.cw_mul(inv_diagonal[i], ri)
    r[i] = ri
    z[i] = zi
    q[i] = wp.vec3(0.0)
    wp.atomic_add(rz, k + 1, wp.dot(ri, zi))


@wp.kernel
def cg_direction(
    k: int,
    z: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
    threshold: wp.array(dtype=float),
    p: wp.array(dtype=wp.vec3),
):
    """p = z + (rz[k+1] / rz[k]) p."""
    if rz[k + 1] <= threshold[0]:
        return
    i = wp.tid()
    p[i] = z[i] + (rz[k + 1] / rz[k]) * p[i]


# -- kernels of the same system as a warp.optim.linear LinearOperator (for the benchmark that
#    compares this fused loop with warp.optim.linear.cg) ----------------------------------


@wp.kernel
def operator_mass_axpby(
    x: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    inv_diagonal: wp.array(dtype=wp.vec3),
    mass_scale: wp.array(dtype=float),
    alpha: float,
    beta: float,
    z: wp.array(dtype=wp.vec3),
):
    """z = beta y + alpha m x (free vertices) or beta y + alpha x (fixed: identity rows)."""
    i = wp.tid()
    m = mass_scale[i]
    if inv_diagonal[i][0] == 0.0:
        m = 1.0
    z[i] = beta * y[i] + (alpha * m) * x[i]


@wp.kernel
def operator_restore_fixed_rows(
    x: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    inv_diagonal: wp.array(dtype=wp.vec3),
    alpha: float,
    beta: float,
    z: wp.array(dtype=wp.vec3),
):
    """Undo the element products on fixed rows: z = beta y + alpha x there."""
    i = wp.tid()
    if inv_diagonal[i][0] == 0.0:
        z[i] = beta * y[i] + alpha * x[i]


@wp.kernel
def jacobi_axpby(
    x: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    inv_diagonal: wp.array(dtype=wp.vec3),
    alpha: float,
    beta: float,
    z: wp.array(dtype=wp.vec3),
):
    """z = alpha D^-1 x + beta y, with D^-1 = I on fixed rows."""
    i = wp.tid()
    d = inv_diagonal[i]
    if d[0] == 0.0:
        d = wp.vec3(1.0)
    z[i] = alpha * wp.cw_mul(d, x[i]) + beta * y[i]
