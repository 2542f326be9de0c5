"""Fused preconditioned conjugate gradient on nodal vec3 arrays, with its loop on the device.

The solve starts from ``x = 0`` (a cold start: a truncated solve warm-started from the last
step's ``dv`` keeps that ``dv`` in the modes it has not yet converged, an explicit
extrapolation of the velocity that grows without bound on a stiff object). It stops on the
Jacobi-scaled residual ``rd = r.D^-1 r`` (D the diagonal of A), relative to ``b.D^-1 b``,
whatever the preconditioner P: with P = D it is ``r.z``; with a factor it costs no solve,
so a step that converges in one iteration applies the factor once. And it stops only once
the largest Jacobi velocity error ``max |D^-1 r|`` (m/s) is below the tolerance times the
largest ``|D^-1 b|``: in the sum ``r.D^-1 r`` the nodes of a small piece weigh almost
nothing, and stopped on it alone the solve left a free element of 1e-4 m beside a 0.1 m
beam with a velocity error that stretched it 1e5 times in volume in two steps (the test
costs ``organ_cut`` 484 iterations in 90 frames instead of 441, and SOFA's beam at 0.1-10 MPa
at most 3% more). One iteration ``k``
(read from ``counter[0]``) is:

1. with a factor: ``z = P^-1 r``, ``rz[k] = r.z`` (``wcut.kernels.cholesky``);
2. :func:`cg_direction`: ``p = z + beta p`` (``beta = rz[k] / rz[k-1]``, 0 at ``k = 0``);
3. the element (and attachment) products into ``q``;
4. :func:`cg_apply_mass`: ``q = A p``, ``pq[k] = p.q``;
5. :func:`cg_update`: x, r and ``rd[k+1]``; with Jacobi also ``z = D^-1 r`` (and ``rz`` is
   ``rd``);
6. :func:`cg_advance`: ``counter += 1``, and ``running`` while ``rd[k+1]`` or the velocity
   error is above its threshold and below the iteration cap.

The scalars live on the device, one slot per iteration, so an iteration never reads back to
the host: the loop is one ``wp.capture_while`` on ``running``, recorded once (CPU) or captured
as a conditional graph node (CUDA), and a converged solve launches nothing more.
Fixed vertices have a zero ``D^-1``; their r, z, p stay zero.

Each thread of the node kernels takes ``chunk`` consecutive nodes
(:func:`wcut.kernels.ranges.thread_range`) and adds its share of a dot product once. On the
CPU, where Warp runs the threads one after another, a chunk of 64 keeps the running sum in a
register instead of every node adding to the same address and waiting for the previous add;
on CUDA a chunk of 1 keeps neighbouring threads on neighbouring nodes (coalesced loads).
"""

import warp as wp

from .partial_sums import take_partials
from .ranges import thread_range


@wp.func
def largest_component(v: wp.vec3) -> float:
    """max(|v_x|, |v_y|, |v_z|)."""
    return wp.max(wp.max(wp.abs(v[0]), wp.abs(v[1])), wp.abs(v[2]))


@wp.kernel
def cg_init(
    chunk: int,
    jacobi: int,
    rhs: wp.array(dtype=wp.vec3),
    inv_diagonal: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    rd: wp.array(dtype=float),
    velocity: wp.array(dtype=float),
):
    """x = 0, r = b, p = 0, q = 0, rd[0] = b.D^-1 b, velocity[0] = max |D^-1 b| (m/s, the
    largest velocity change of the Jacobi step); with ``jacobi`` also z = D^-1 r."""
    lo, hi = thread_range(wp.tid(), chunk, x.shape[0])
    zero = wp.vec3(0.0)
    rd_sum = float(0.0)
    largest = float(0.0)
    for i in range(lo, hi):
        d = inv_diagonal[i]
        b = zero
        if d[0] != 0.0:  # (a fixed vertex is outside the system)
            b = rhs[i]
        x[i] = zero
        r[i] = b
        p[i] = zero
        q[i] = zero
        zi = wp.cw_mul(d, b)
        if jacobi != 0:
            z[i] = zi
        rd_sum += wp.dot(b, zi)
        largest = wp.max(largest, largest_component(zi))
    wp.atomic_add(rd, 0, rd_sum)
    wp.atomic_max(velocity, 0, largest)


@wp.kernel
def cg_start(tolerance_sq: float, max_iterations: int, rd: wp.array(dtype=float), velocity: wp.array(dtype=float),
             norms: wp.array(dtype=float), running: wp.array(dtype=wp.int32)):
    """One thread: ``norms = (tol^2 b.D^-1 b, b.D^-1 b, tol max |D^-1 b|)``; run while
    ``rd[0]`` is above 0."""
    norms[0] = tolerance_sq * rd[0]
    norms[1] = rd[0]
    norms[2] = wp.sqrt(tolerance_sq) * velocity[0]
    running[0] = wp.where(rd[0] > 0.0 and max_iterations > 0, 1, 0)


@wp.kernel
def cg_direction(
    chunk: int,
    counter: wp.array(dtype=wp.int32),
    z: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
    p: wp.array(dtype=wp.vec3),
):
    """p = z + (rz[k] / rz[k-1]) p (p = z at k = 0)."""
    k = counter[0]
    beta = float(0.0)
    if k > 0:
        beta = rz[k] / rz[k - 1]
    lo, hi = thread_range(wp.tid(), chunk, p.shape[0])
    for i in range(lo, hi):
        p[i] = z[i] + beta * p[i]


@wp.kernel
def cg_apply_mass(
    chunk: int,
    counter: wp.array(dtype=wp.int32),
    inv_diagonal: wp.array(dtype=wp.vec3),
    mass_scale: wp.array(dtype=float),
    p: wp.array(dtype=wp.vec3),
    partials: wp.array2d(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    pq: wp.array(dtype=float),
):
    """q = A p (adding the mass term and the rows of ``partials`` to the stiffness part
    already in q, and clearing those rows); pq[k] = p.q.

    ``partials`` holds the scatters of an element product split over CPU threads
    (``wcut.split_launch``); it has no rows otherwise."""
    k = counter[0]
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
    jacobi: int,
    counter: wp.array(dtype=wp.int32),
    inv_diagonal: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    pq: wp.array(dtype=float),
    rz: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    rd: wp.array(dtype=float),
    velocity: wp.array(dtype=float),
):
    """x += alpha p, r -= alpha q, q = 0 (alpha = rz[k] / pq[k]), rd[k+1] = r.D^-1 r,
    velocity[k+1] = max |D^-1 r| (m/s); with ``jacobi`` also z = D^-1 r (``rd`` is then
    ``rz``)."""
    k = counter[0]
    alpha = float(0.0)
    if pq[k] > 0.0:
        alpha = rz[k] / pq[k]
    lo, hi = thread_range(wp.tid(), chunk, x.shape[0])
    rd_sum = float(0.0)
    largest = float(0.0)
    for i in range(lo, hi):
        x[i] = x[i] + alpha * p[i]
        ri = r[i] - alpha * q[i]
        r[i] = ri
        q[i] = wp.vec3(0.0)
        zi = wp.cw_mul(inv_diagonal[i], ri)
        if jacobi != 0:
            z[i] = zi
        rd_sum += wp.dot(ri, zi)
        largest = wp.max(largest, largest_component(zi))
    wp.atomic_add(rd, k + 1, rd_sum)
    wp.atomic_max(velocity, k + 1, largest)


@wp.kernel
def cg_advance(max_iterations: int, rd: wp.array(dtype=float), velocity: wp.array(dtype=float),
               norms: wp.array(dtype=float), counter: wp.array(dtype=wp.int32),
               running: wp.array(dtype=wp.int32)):
    """One thread, after iteration k: ``counter = k + 1``; go on while ``rd[k+1]`` or
    ``velocity[k+1]`` is above its threshold and fewer than ``max_iterations`` iterations ran."""
    k = counter[0] + 1
    counter[0] = k
    running[0] = wp.where((rd[k] > norms[0] or (velocity[k] > norms[2] and rd[k] > 0.0)) and k < max_iterations, 1, 0)


@wp.kernel
def listed_apply_mass(
    nodes: wp.array(dtype=wp.int32),
    inv_diagonal: wp.array(dtype=wp.vec3),
    mass_scale: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
):
    """The mass term of ``y = A x`` at the listed (distinct) nodes, as :func:`cg_apply_mass`
    adds it: ``y_i += m_i x_i``, or 0 at a fixed node."""
    i = nodes[wp.tid()]
    if inv_diagonal[i][0] == 0.0:
        y[i] = wp.vec3(0.0)
    else:
        y[i] = y[i] + mass_scale[i] * x[i]


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
