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

Each thread of the node kernels takes ``chunk`` consecutive nodes
(:func:`wcut.kernels.ranges.thread_range`) and adds its share of a dot product once. On the
CPU, where Warp runs the threads one after another, a chunk of 64 keeps the running sum in a
register instead of every node adding to the same address and waiting for the previous add;
on CUDA a chunk of 1 keeps neighbouring threads on neighbouring nodes (coalesced loads).

(Folding ``p.q`` into the element product, to save :func:`cg_apply_mass`, was measured slower
on the CPU: the per-element add to one address serialises the element loop.)
"""

import warp as wp

from .partial_sums import take_partials
from .ranges import thread_range


@wp.kernel
def cg_init(
    chunk: int,
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
    lo, hi = thread_range(wp.tid(), chunk, x.shape[0])
    zero = wp.vec3(0.0)
    rz_sum = float(0.0)
    bb_sum = float(0.0)
    for i in range(lo, hi):
        d = inv_diagonal[i]
        if d[0] == 0.0:  # fixed vertex: outside the system
            x[i] = zero
            r[i] = zero
            z[i] = zero
            p[i] = zero
        else:
            b = rhs[i]
            ri = b - (q[i] + mass_scale[i] * x[i])
            zi = wp.cw_mul(d, ri)
            r[i] = ri
            z[i] = zi
            p[i] = zi
            rz_sum += wp.dot(ri, zi)
            bb_sum += wp.dot(b, wp.cw_mul(d, b))
        q[i] = zero
    wp.atomic_add(rz, 0, rz_sum)
    wp.atomic_add(norms, 0, tolerance_sq * bb_sum)
    wp.atomic_add(norms, 1, bb_sum)


@wp.kernel
def cg_apply_mass(
    chunk: int,
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
    lo, hi = thread_range(wp.tid(), chunk, p.shape[0])
    pq_sum = float(0.0)
    for i in range(lo, hi):
        qi = take_partials(partials, i, q[i])
        if inv_diagonal[i][0] == 0.0:
            q[i] = wp.vec3(0.0)
        else:
            pi = p[i]
            qi = qi + mass_scale[i] * pi
            q[i] = qi
            pq_sum += wp.dot(pi, qi)
    wp.atomic_add(pq, k, pq_sum)


@wp.kernel
def cg_update(
    chunk: int,
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
    if rz[k] <= threshold[0]:
        if wp.tid() == 0:
            rz[k + 1] = rz[k]
        return
    alpha = float(0.0)
    if pq[k] > 0.0:
        alpha = rz[k] / pq[k]
    lo, hi = thread_range(wp.tid(), chunk, x.shape[0])
    rz_sum = float(0.0)
    for i in range(lo, hi):
        x[i] = x[i] + alpha * p[i]
        ri = r[i] - alpha * q[i]
        zi = wp.cw_mul(inv_diagonal[i], ri)
        r[i] = ri
        z[i] = zi
        q[i] = wp.vec3(0.0)
        rz_sum += wp.dot(ri, zi)
    wp.atomic_add(rz, k + 1, rz_sum)


@wp.kernel
def cg_direction(
    chunk: int,
    k: int,
    z: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
    threshold: wp.array(dtype=float),
    p: wp.array(dtype=wp.vec3),
):
    """p = z + (rz[k+1] / rz[k]) p."""
    if rz[k + 1] <= threshold[0]:
        return
    beta = rz[k + 1] / rz[k]
    lo, hi = thread_range(wp.tid(), chunk, p.shape[0])
    for i in range(lo, hi):
        p[i] = z[i] + beta * p[i]


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
