"""A rotated sparse Cholesky factor applied as a preconditioner (``wcut.preconditioner``).

The factor is ``L L^T = Q^T A0 Q`` of the rest system matrix ``A0`` (free nodes only, in the
fill-reducing order ``Q``), stored by 3x3 blocks, row-wise: block row ``I`` holds its strictly
lower blocks ``L_IJ`` (``J < I``, columns ``block_column[row_start[I]:row_start[I+1]]``) and
the inverse of its lower-triangular diagonal block, ``diagonal_inverse[I] = L_II^-1``.

Applied to a residual ``r`` (Courtecuisse et al. 2010, 2014): ``z_i = R_i sum_k w_ik
[(L L^T)^-1 t]_I(i,k)`` with ``t_I = sum w_ik R_i^T r_i`` over the nodes ``i`` and slots ``k``
with ``I(i, k) = factor_rows[i, k]``, ``w_ik = factor_weights[i, k]``, and ``R_i`` the rotation
of node ``i`` (:func:`node_rotations_tet`, :func:`node_rotations_gauss`), so the factor of the
rest shape serves an object that has turned. For linear elements a node has one row, weight 1;
for quadratic elements the factor is of the corners and a node is interpolated from up to two
(``wcut.preconditioner``), with ``D_i^-1 r_i`` added (``smoother``). A node without a row (-1:
added or changed by a topological change since the factorization) gets the Jacobi
preconditioner ``z_i = D_i^-1 r_i``; a fixed node gets 0. A node of the patch
(``patch_position[i] >= 0``, listed in ``patch_nodes``) takes the second, small factor of the
patch instead, before and after the factor (:func:`rotate_into_patch`, :func:`rotate_from_patch`;
the symmetric multiplicative combination of ``wcut.preconditioner``).

The triangular solves (:func:`block_forward`, :func:`block_backward`) run on one thread each:
a row needs the rows before it. On the CPU, where Warp runs threads one after another anyway,
that costs nothing; on CUDA the kernels are correct but serial. The rows of two disjoint
subtrees of the factor's elimination tree do not use each other's, so on the CPU the two run
on two threads at once (``wcut.preconditioner``). The rows above them (the top separators)
hold most of their blocks in the subtrees' columns; each thread also takes those of its
subtree (:func:`block_forward_gather` after its forward pass, :func:`block_backward_scatter`
before its backward pass), and only the blocks among the top rows run alone
(:func:`block_forward_top`, and :func:`block_backward` from each top row's first block in a
top column).
"""

import warp as wp

from .ranges import thread_range


@wp.kernel
def node_rotations_tet(
    owner: wp.array(dtype=wp.int32),
    tet_rotation: wp.array(dtype=wp.quat),
    node_rotation: wp.array(dtype=wp.quat),
):
    """``R_i``: the rotation of the element that owns node i (its largest incident element)."""
    i = wp.tid()
    o = owner[i]
    if o >= 0:
        node_rotation[i] = tet_rotation[o]


@wp.kernel
def node_rotations_gauss(
    owner: wp.array(dtype=wp.int32),
    tet_rotation: wp.array2d(dtype=wp.quat),
    node_rotation: wp.array(dtype=wp.quat),
):
    """``R_i`` of quadratic elements: the rotation at the Gauss point ``owner % 4`` of element
    ``owner / 4`` (the point nearest the node)."""
    i = wp.tid()
    o = owner[i]
    if o >= 0:
        node_rotation[i] = tet_rotation[o // 4, o % 4]


@wp.kernel
def rotate_into_factor(
    chunk: int,
    subtract: int,
    factor_rows: wp.array2d(dtype=wp.int32),
    factor_weights: wp.array2d(dtype=float),
    patch_position: wp.array(dtype=wp.int32),
    node_rotation: wp.array(dtype=wp.quat),
    r: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    t: wp.array(dtype=wp.vec3),
):
    """``t[factor_rows[i, k]] += factor_weights[i, k] R_i^T u_i`` for the nodes outside the
    patch (``t`` zero before), ``u = r - y`` with ``subtract``, else ``r``."""
    lo, hi = thread_range(wp.tid(), chunk, r.shape[0])
    for i in range(lo, hi):
        if patch_position[i] < 0:
            ri = r[i]
            if subtract != 0:
                ri = ri - y[i]
            u = wp.quat_rotate_inv(node_rotation[i], ri)
            for k in range(2):
                row = factor_rows[i, k]
                if row >= 0:
                    wp.atomic_add(t, row, factor_weights[i, k] * u)


@wp.kernel
def rotate_into_patch(
    patch_nodes: wp.array(dtype=wp.int32),
    node_rotation: wp.array(dtype=wp.quat),
    subtract: int,
    r: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    t_patch: wp.array(dtype=wp.vec3),
):
    """``t_patch[k] = R_i^T u_i`` for node ``i = patch_nodes[k]``, ``u = r - y`` with
    ``subtract``, else ``r``."""
    k = wp.tid()
    i = patch_nodes[k]
    ri = r[i]
    if subtract != 0:
        ri = ri - y[i]
    t_patch[k] = wp.quat_rotate_inv(node_rotation[i], ri)


@wp.kernel
def rotate_from_patch(
    patch_nodes: wp.array(dtype=wp.int32),
    node_rotation: wp.array(dtype=wp.quat),
    counter: wp.array(dtype=wp.int32),
    correct: int,
    r: wp.array(dtype=wp.vec3),
    t_patch: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
):
    """For node ``i = patch_nodes[k]``: ``z_i = R_i t_patch[k]``; with ``correct``, ``z_i +=
    R_i t_patch[k]`` and ``rz[counter] += r_i . R_i t_patch[k]`` instead."""
    k = wp.tid()
    i = patch_nodes[k]
    w = wp.quat_rotate(node_rotation[i], t_patch[k])
    if correct != 0:
        z[i] = z[i] + w
        wp.atomic_add(rz, counter[0], wp.dot(r[i], w))
    else:
        z[i] = w


@wp.func
def less_block_products(
    acc: wp.vec3,
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    first: int,
    last: int,
    t: wp.array(dtype=wp.vec3),
):
    """``acc - sum L_b t[column b]`` over the blocks ``first..last-1``, subtracted in order."""
    out = acc
    for b in range(first, last):
        out = out - blocks[b] * t[block_column[b]]
    return out


@wp.func
def scatter_block_products(
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    first: int,
    last: int,
    x: wp.vec3,
    t: wp.array(dtype=wp.vec3),
):
    """``t[column b] -= L_b^T x`` over the blocks ``first..last-1`` (a solved row's share of a
    backward substitution)."""
    for b in range(first, last):
        c = block_column[b]
        t[c] = t[c] - wp.transpose(blocks[b]) * x


@wp.kernel
def block_forward(
    row_start: wp.array(dtype=wp.int32),
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    diagonal_inverse: wp.array(dtype=wp.mat33),
    lo: int,
    hi: int,
    t: wp.array(dtype=wp.vec3),
):
    """One thread: forward substitution ``L y = t`` in place over the block rows ``lo..hi-1``
    (the rows they use before ``lo`` already solved)."""
    for row in range(lo, hi):
        acc = less_block_products(t[row], block_column, blocks, row_start[row], row_start[row + 1], t)
        t[row] = diagonal_inverse[row] * acc


@wp.kernel
def block_backward(
    row_start: wp.array(dtype=wp.int32),
    first_block: wp.array(dtype=wp.int32),
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    diagonal_inverse: wp.array(dtype=wp.mat33),
    lo: int,
    t: wp.array(dtype=wp.vec3),
):
    """One thread: backward substitution ``L^T x = y`` in place over the block rows ``lo ..
    lo + len(first_block) - 1``, last to first, each row scattered to the rows of its blocks
    ``first_block[k] .. row_start[row + 1] - 1`` (``row_start[lo:]`` for all of them; the rows
    after, and the rows of the blocks left out, already done)."""
    count = first_block.shape[0]
    for j in range(count):
        k = count - 1 - j
        row = lo + k
        x = wp.transpose(diagonal_inverse[row]) * t[row]
        t[row] = x
        scatter_block_products(block_column, blocks, first_block[k], row_start[row + 1], x, t)


@wp.kernel
def block_forward_gather(
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    segment_start: wp.array(dtype=wp.int32),
    segment_end: wp.array(dtype=wp.int32),
    t: wp.array(dtype=wp.vec3),
    acc: wp.array(dtype=wp.vec3),
):
    """One thread: ``acc[k] = sum L_b t[column b]`` over the blocks ``segment_start[k] ..
    segment_end[k] - 1`` of top row k (blocks in one subtree's columns, already solved)."""
    for k in range(acc.shape[0]):  # (-(0 - a - b) is a + b to the bit: rounding is symmetric)
        acc[k] = -less_block_products(wp.vec3(0.0), block_column, blocks, segment_start[k], segment_end[k], t)


@wp.kernel
def block_forward_top(
    row_start: wp.array(dtype=wp.int32),
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    diagonal_inverse: wp.array(dtype=wp.mat33),
    top_start: wp.array(dtype=wp.int32),
    lo: int,
    acc_a: wp.array(dtype=wp.vec3),
    acc_b: wp.array(dtype=wp.vec3),
    t: wp.array(dtype=wp.vec3),
):
    """One thread: forward substitution over the top rows ``lo..`` given the sums of their
    blocks in the two subtrees' columns (``acc_a``, ``acc_b``, :func:`block_forward_gather`);
    ``top_start[k]`` is the first block of row ``lo + k`` in a top column."""
    for k in range(acc_a.shape[0]):
        row = lo + k
        acc = less_block_products(t[row] - acc_a[k] - acc_b[k], block_column, blocks, top_start[k],
                                  row_start[row + 1], t)
        t[row] = diagonal_inverse[row] * acc


@wp.kernel
def block_backward_scatter(
    block_column: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    segment_start: wp.array(dtype=wp.int32),
    segment_end: wp.array(dtype=wp.int32),
    lo: int,
    t: wp.array(dtype=wp.vec3),
):
    """One thread: ``t[column b] -= L_b^T t[lo + k]`` over the blocks ``segment_start[k] ..
    segment_end[k] - 1`` of each top row k (solved): the top rows' share of one subtree's
    backward substitution."""
    for k in range(segment_start.shape[0]):
        scatter_block_products(block_column, blocks, segment_start[k], segment_end[k], t[lo + k], t)


@wp.kernel
def rotate_from_factor(
    chunk: int,
    counter: wp.array(dtype=wp.int32),
    smoother: int,
    factor_rows: wp.array2d(dtype=wp.int32),
    factor_weights: wp.array2d(dtype=float),
    patch_position: wp.array(dtype=wp.int32),
    node_rotation: wp.array(dtype=wp.quat),
    inv_diagonal: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    t: wp.array(dtype=wp.vec3),
    t_patch: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    rz: wp.array(dtype=float),
):
    """``z_i = R_i t_patch[patch_position[i]]`` for a node of the patch; else ``R_i sum_k
    factor_weights[i, k] t[factor_rows[i, k]]``, plus ``D_i^-1 r_i`` with ``smoother`` (the
    two-level preconditioner of quadratic elements) or where the node has no row (0 for a
    fixed one); and ``rz[counter] = r.z``."""
    lo, hi = thread_range(wp.tid(), chunk, r.shape[0])
    rz_sum = float(0.0)
    for i in range(lo, hi):
        p = patch_position[i]
        ri = r[i]
        jacobi = wp.cw_mul(inv_diagonal[i], ri)
        zi = jacobi
        if p >= 0:
            zi = wp.quat_rotate(node_rotation[i], t_patch[p])
        elif factor_rows[i, 0] >= 0:
            acc = factor_weights[i, 0] * t[factor_rows[i, 0]]
            if factor_rows[i, 1] >= 0:
                acc = acc + factor_weights[i, 1] * t[factor_rows[i, 1]]
            zi = wp.quat_rotate(node_rotation[i], acc)
            if smoother != 0:
                zi = zi + jacobi
        z[i] = zi
        rz_sum += wp.dot(ri, zi)
    wp.atomic_add(rz, counter[0], rz_sum)
