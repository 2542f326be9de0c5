"""The conjugate gradient's preconditioner: a rotated sparse Cholesky factor of the rest system.

Following Courtecuisse, Jung, Allard, Duriez, Lee and Cotin (2010, 2014), the system matrix of
the rest shape, ``A0 = (1 + h alpha) M + (h^2 + h beta) K0 + h^2 K_attach`` (the matrix of
``wcut.kernels.implicit_euler`` with every rotation the identity), is factored once,
``L L^T = Q^T A0 Q``, and applied rotated per node: ``P^-1 r = R (Q L^-T L^-1 Q^T) R^T r``, with
``R_i`` the rotation of an element around node ``i`` (``wcut.kernels.cholesky``). While an
object deforms and turns, ``P`` stays close to the tangent system, so the conjugate gradient
converges in a few iterations at any stiffness.

Measured on SOFA's 10x10x40 beam at E = 1 MPa, dt = 1/60 s, relative residual 1e-6 from rest:
Jacobi 199 iterations, 3x3 block Jacobi 191, smoothed-aggregation AMG (pyamg) 8 iterations at
10 ms per V-cycle in Python, the rest factor 1 (2 ms per application on one CPU thread). The
factor is kept: it converges fastest in time, and its solves run as Warp kernels inside the
recorded or captured step.

Quadratic elements get two levels: the factor of the Galerkin projection ``Pi^T A0 Pi`` of the
rest matrix on the linear functions of the free corners (``Pi`` interpolates: 1 at a corner,
1/2 at the middle of its edges), applied rotated, plus Jacobi on every node (``wcut.kernels.
cholesky``, ``smoother``): ``P^-1 = R Pi (Pi^T A0 Pi)^-1 Pi^T R^T + D^-1``, a p-multigrid
preconditioner in additive form. The factor of the whole quadratic system is far too dense: on
the 10000-element P2 beam of ``wcut bench`` it has 2.2 million blocks, takes some 16 s to
compute and 20-25 ms per application, so a step took 104 ms with 3 iterations; the corners'
factor has 104 thousand blocks and the step 63 ms with 10 iterations (side by side). A
symmetric V-cycle (Jacobi, corners, Jacobi) needed 4-5 iterations against the additive form's
7-11 (rest matrix, four right-hand sides), but three products by A per iteration: no faster.

The factorization is SuperLU's (scipy) on a nested-dissection order of the nodes (METIS,
through pymetis), without pivoting (``A0`` is symmetric positive definite), its ``L`` taken
apart into 3x3 blocks. Scipy has no sparse Cholesky of its own; SuperLU's LU of a symmetric
matrix in symmetric mode is ``L D L^T``.

After a topological change (:meth:`RotatedCholesky.carried`) the factor of before keeps
serving the vertices the change left alone. The vertices of the elements it changed get a
*patch*: the factor of the new rest matrix on those nodes alone, ``A0[S][:, S]``, computed at
the next step (a few milliseconds: it holds some hundred nodes). A
new factor of the whole new model is computed on a background thread (SuperLU releases the GIL)
and taken at the first step after it is ready. The same happens when the time step or the
damping change. The patch's nodes are left out of the factor of before, and the two combine
as a symmetric multiplicative Schwarz preconditioner: with ``B_S`` the rotated patch solve and
``B_F`` the rotated factor of before on the other nodes,

    z1 = B_S r,    z2 = z1 + B_F (r - A z1),    P^-1 r = z2 + B_S (r - A z2),

A the system matrix of the step. Its two products touch only the elements around the patch
(``product`` of :meth:`RotatedCholesky.record_apply`): ``z1`` is zero elsewhere, and of
``A z2`` only the patch's rows are read. It is symmetric, and positive definite whenever
``B_S`` does not overshoot the patch's matrix by a factor two (``I - B_S A`` is then an
A-contraction, and ``B_F`` is positive on every other node). The sum of the two (an additive
combination) drops the coupling of the patch to the rest: on the organ midway through
``organ_cut``'s cut (109-146 nodes outside the factor, patches of 225-283 nodes, rest
matrices, three right-hand sides, relative residual 1e-2), the sum needed 9-36 iterations,
the multiplicative form 1-2; over the scene's run, 1624 iterations became 459. The sum needs
the patch to hold the nodes' neighbours too; the product does not: with them, the run took
438 iterations, but making a patch took twice as long.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from .errors import SimulationError
from .kernels import cholesky


# -- the rest system matrix --------------------------------------------------------------------


def _stiffness_blocks(nodes: np.ndarray, gradients: np.ndarray, coefficients: np.ndarray,
                      selected: np.ndarray | None = None):
    """Node pairs and 3x3 blocks of isotropic elastic stiffness at quadrature points.

    For point q with nodes ``n_a`` (Q, k), gradients ``g_a`` (Q, k, 3) in 1/m and
    ``coefficients (V mu, V lambda)`` (Q, 2) in N*m, the block of nodes (a, b) is
    ``V mu (g_a . g_b) I + V mu g_b g_a^T + V lambda g_a g_b^T`` (N/m; thesis eq. 3.48).
    Returns rows, columns and blocks (9, P) (component-major: numpy's loops over 3x3 blocks
    cost 6x more) of the pairs in (q, a, b) order: all of them, or with ``selected`` (N,) bool
    those whose two nodes are selected (a patch's few rows need a fraction of its elements'
    blocks)."""
    Q, k = nodes.shape
    if selected is None:
        q, a, b = (i.ravel() for i in np.indices((Q, k, k)))
    else:
        inside = selected[nodes]
        q, a, b = np.nonzero(inside[:, :, None] & inside[:, None, :])
    ga, gb = np.ascontiguousarray(gradients[q, a].T), np.ascontiguousarray(gradients[q, b].T)  # (3, P)
    vmu, vlam = coefficients[q, 0], coefficients[q, 1]
    # [i, j]: V mu (g_b)_i (g_a)_j + V lambda (g_a)_i (g_b)_j, then V mu g_a . g_b on the diagonal
    blocks = gb[:, None, :] * (vmu * ga)[None, :, :] + (vlam * ga)[:, None, :] * gb[None, :, :]
    blocks[[0, 1, 2], [0, 1, 2]] += vmu * (ga * gb).sum(axis=0)
    return nodes[q, a], nodes[q, b], blocks.reshape(9, -1)


def _spring_blocks(indices: np.ndarray, weights: np.ndarray, stiffness: np.ndarray):
    """Node pairs and blocks (9, P) ``k w_a w_b I`` of springs on weighted points (attachments)."""
    k = indices.shape[1]
    scalar = stiffness[:, None, None] * weights[:, :, None] * weights[:, None, :]
    rows = np.repeat(indices, k, axis=1).ravel()
    cols = np.tile(indices, (1, k)).ravel()
    return rows, cols, _scalar_blocks(scalar.reshape(-1))


def _scalar_blocks(values: np.ndarray) -> np.ndarray:
    """Blocks ``v I`` (9, P) of scalars ``values`` (P,)."""
    return np.eye(3).reshape(9, 1) * values[None, :]


@dataclass
class RestData:
    """A snapshot of what the rest system matrix of a model derives from (host arrays, float64),
    taken on the calling thread so that a background factorization reads nothing that a later
    rebuild in place may overwrite."""

    node_count: int
    fixed: np.ndarray
    mass: np.ndarray
    parts: list  # (kind, arrays...) per element family and spring set

    @classmethod
    def of(cls, model) -> "RestData":
        parts = []
        f64 = lambda a: a.numpy().astype(np.float64)  # noqa: E731
        if model.tet_count:
            parts.append(("tet", model.tet_order, model.tet_indices.numpy().astype(np.int64), f64(model.tet_poses),
                          f64(model.tet_stiffness)))
        if model.attachment_count:
            parts.append(("spring", model.attachment_indices.numpy().astype(np.int64),
                          f64(model.attachment_weights), f64(model.attachment_stiffness)))
        return cls(model.particle_count, model.particle_fixed.numpy() != 0, f64(model.particle_mass), parts)


def _element_blocks(part, chunk: int = 2048, fixed: np.ndarray | None = None, selected: np.ndarray | None = None):
    """Yield (rows, cols, blocks) of the stiffness of one element family of :class:`RestData`:
    with ``selected`` (N bool), only the blocks between selected nodes. With ``fixed`` (the
    fixed-node mask, N bool) a quadratic family's stiffness is projected on the linear
    functions of its corners (:func:`coarse_system_matrix`): rows and columns are corners,
    and a fixed node's value is 0."""
    if part[0] == "tet" and part[1] == 1:
        _, _, tets, poses, stiffness = part
        grads = np.concatenate([poses, -poses.sum(axis=1, keepdims=True)], axis=1)  # rows grad N_0..3
        for s in range(0, len(tets), chunk):
            yield _stiffness_blocks(tets[s:s + chunk], grads[s:s + chunk], stiffness[s:s + chunk], selected)
    elif part[0] == "tet":
        from . import p2

        _, _, tets, poses, stiffness = part
        dN = p2.shape_gradients(p2.GAUSS_POINTS)  # (4, 10, 3) in xi
        for s in range(0, len(tets), chunk):
            cells = tets[s:s + chunk]
            grads = np.einsum("gaj,mgji->mgai", dN, poses[s:s + chunk])  # grad_X N = J^-T grad_xi N
            if fixed is not None:  # corner c's function is NODE_POINTS[a, c] at node a
                grads = np.einsum("mgai,ac->mgci", grads * ~fixed[cells][:, None, :, None], p2.NODE_POINTS)
                cells = cells[:, :4]
            m, k = cells.shape
            yield _stiffness_blocks(np.repeat(cells, 4, axis=0), grads.reshape(m * 4, k, 3),
                                    stiffness[s:s + chunk].reshape(m * 4, 2), selected)
    else:
        raise ValueError(f"unknown part {part[0]!r}")


def _touching(part, selected: np.ndarray):
    """``part`` of :class:`RestData` with only the elements (or springs) that have a node in
    ``selected`` (N,) bool: the others add nothing to the rows and columns of those nodes."""
    cells = part[2] if part[0] == "tet" else part[1]
    keep = selected[cells].any(axis=1)
    if part[0] == "tet":
        return part[:2] + tuple(a[keep] for a in part[2:])
    return part[:1] + tuple(a[keep] for a in part[1:])


def rest_system_matrix(data: RestData, dt: float, rayleigh_mass: float, rayleigh_stiffness: float,
                       nodes: np.ndarray | None = None):
    """The rest system matrix ``A0`` (kg) on the free nodes, as a block-sparse matrix, and the
    free nodes (ascending). ``A0 = (1 + h alpha) M + (h^2 + h beta) K0 + h^2 K_attach``: the
    matrix the solver's products apply when every element is at rest
    (``wcut.kernels.implicit_euler``). With ``nodes`` (free nodes, ascending), only their rows
    and columns, from the elements around them: ``A0[nodes][:, nodes]``."""
    N = data.node_count
    free = np.flatnonzero(~data.fixed) if nodes is None else np.asarray(nodes, dtype=np.int64)
    index = np.full(N, -1, dtype=np.int64)
    index[free] = np.arange(len(free))
    parts = data.parts if nodes is None else [_touching(part, index >= 0) for part in data.parts]
    scale = dt * dt + dt * rayleigh_stiffness
    rows, cols = [free], [free]
    blocks = [_scalar_blocks((1.0 + dt * rayleigh_mass) * data.mass[free])]
    for part in parts:
        if part[0] == "spring":
            r, c, b = _spring_blocks(*part[1:3], part[3] * dt * dt)
            keep = (index[r] >= 0) & (index[c] >= 0)
            rows.append(r[keep]), cols.append(c[keep]), blocks.append(b[:, keep])
            continue
        for r, c, b in _element_blocks(part, selected=index >= 0):  # (only the blocks between free nodes)
            rows.append(r), cols.append(c), blocks.append(scale * b)
    return _block_matrix(index[np.concatenate(rows)], index[np.concatenate(cols)], np.concatenate(blocks, axis=1),
                         len(free)), free


def _block_matrix(rows: np.ndarray, cols: np.ndarray, blocks: np.ndarray, n: int) -> sp.bsr_matrix:
    """The (3n, 3n) block-sparse sum of 3x3 ``blocks`` (9, P) at block ``(rows, cols)``."""
    unique, inverse = np.unique(rows * n + cols, return_inverse=True)
    summed = np.stack([np.bincount(inverse, weights=blocks[c], minlength=len(unique)) for c in range(9)], axis=1)
    block_rows, block_cols = unique // n, unique % n
    indptr = np.searchsorted(block_rows, np.arange(n + 1))
    return sp.bsr_matrix((summed.reshape(-1, 3, 3), block_cols, indptr), shape=(3 * n, 3 * n))


def _coarse_space(data: RestData, free: np.ndarray):
    """Of a quadratic model: the interpolation ``Pi`` (free nodes x free corners, CSR) of
    linear functions on the corners (1 at a corner, 1/2 at the middle of its edges), whose
    columns are the free corners, and per node its column (-1: none)."""
    from . import p2

    tets = next(part[2] for part in data.parts if part[0] == "tet")
    corner = np.full(data.node_count, -1, dtype=np.int64)
    corners = np.unique(tets[:, :4])
    corners = corners[~data.fixed[corners]]
    corner[corners] = np.arange(len(corners))
    middles, first = np.unique(tets[:, 4:].ravel(), return_index=True)
    ends = tets[:, p2.EDGES].reshape(-1, 2)[first]  # the corners of each edge node, once
    rows = np.concatenate([corners, np.repeat(middles, 2)])
    cols = np.concatenate([corner[corners], corner[ends.ravel()]])
    weights = np.concatenate([np.ones(len(corners)), np.full(ends.size, 0.5)])
    row = np.full(data.node_count, -1, dtype=np.int64)
    row[free] = np.arange(len(free))
    keep = (row[rows] >= 0) & (cols >= 0)
    return sp.csr_matrix((weights[keep], (row[rows[keep]], cols[keep])), shape=(len(free), len(corners))), corner


def coarse_system_matrix(data: RestData, dt: float, rayleigh_mass: float, rayleigh_stiffness: float):
    """Of a quadratic model: ``Pi^T A0 Pi`` (kg), the rest system matrix projected on the linear
    functions of the free corners (:func:`_coarse_space`), without assembling ``A0``: an
    element's stiffness is bilinear in its nodes' shape gradients, so its projection is the
    stiffness of the projected gradients ``sum_a Pi_ac grad N_a`` (a fixed node's value is 0).
    Returns the matrix and ``Pi`` (free nodes x free corners)."""
    free = np.flatnonzero(~data.fixed)
    Pi, corner = _coarse_space(data, free)
    # the mass and springs: scalar matrices on the free nodes, projected
    scalar = sp.diags((1.0 + dt * rayleigh_mass) * data.mass[free])
    index = np.full(data.node_count, -1, dtype=np.int64)
    index[free] = np.arange(len(free))
    rows, cols, blocks = [], [], []
    for part in data.parts:
        if part[0] == "spring":
            r, c, b = _spring_blocks(*part[1:3], part[3] * dt * dt)
            keep = (index[r] >= 0) & (index[c] >= 0)
            scalar = scalar + sp.csr_matrix((b[0, keep], (index[r[keep]], index[c[keep]])), shape=scalar.shape)
            continue
        for r, c, b in _element_blocks(part, fixed=data.fixed):
            keep = (corner[r] >= 0) & (corner[c] >= 0)
            rows.append(corner[r[keep]]), cols.append(corner[c[keep]])
            blocks.append((dt * dt + dt * rayleigh_stiffness) * b[:, keep])
    projected = (Pi.T @ sp.csr_matrix(scalar) @ Pi).tocoo()
    rows.append(projected.row), cols.append(projected.col)
    blocks.append(_scalar_blocks(projected.data))
    return _block_matrix(np.concatenate(rows), np.concatenate(cols), np.concatenate(blocks, axis=1), Pi.shape[1]), Pi


# -- the factor --------------------------------------------------------------------------------


def nested_dissection(graph) -> np.ndarray:
    """A fill-reducing order (a permutation of ``0..n-1``) of the nodes of ``graph``, an (n, n)
    sparse matrix whose nonzeros are its edges (the diagonal is ignored): METIS's nested
    dissection, through pymetis."""
    import pymetis

    graph = sp.csr_matrix(graph, copy=True)
    graph.setdiag(0)
    graph.eliminate_zeros()
    n = graph.shape[0]
    if n < 3 or graph.nnz == 0:
        return np.arange(n)
    perm, _ = pymetis.nested_dissection(adjacency=pymetis.CSRAdjacency(graph.indptr, graph.indices))
    return np.asarray(perm, dtype=np.int64)


@dataclass
class BlockFactor:
    """``L L^T = A0[order][:, order]`` by 3x3 blocks (``wcut.kernels.cholesky``): block row I
    of L holds ``blocks[row_start[I]:row_start[I+1]]`` (strictly lower, columns
    ``block_column``) and ``diagonal_inverse[I] = L_II^-1``; ``order[I]`` is the free node
    (index among the free ones) of block row I."""

    order: np.ndarray
    row_start: np.ndarray
    block_column: np.ndarray
    blocks: np.ndarray
    diagonal_inverse: np.ndarray
    #: ``(a, b)``: block rows ``0..a-1`` and ``a..b-1`` are two disjoint subtrees of the
    #: elimination tree (neither uses the other's rows), ``b..`` the rows above them; None when
    #: the tree does not branch
    subtrees: tuple[int, int] | None = None

    @property
    def block_count(self) -> int:
        return len(self.blocks)


def factor(A: sp.bsr_matrix, split: bool = True) -> BlockFactor:
    """The block Cholesky factor of the symmetric positive definite block matrix ``A``; with
    ``split``, its two largest subtrees (:attr:`BlockFactor.subtrees`), else none.

    Raises :class:`SimulationError` when ``A`` is not positive definite (a pivot <= 0)."""
    n = A.shape[0] // 3
    order = nested_dissection(sp.csr_matrix((np.ones(len(A.indices)), A.indices, A.indptr), shape=(n, n)))
    dofs = (3 * order[:, None] + np.arange(3)).ravel()
    A_ordered = A.tocsr()[dofs][:, dofs].tocsc()
    lu = spla.splu(A_ordered, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                   options=dict(SymmetricMode=True))
    # SuperLU post-orders the elimination tree; a node's three rows stay together (they form a
    # chain in the tree), so its permutation is again one of nodes
    perm = lu.perm_c
    if not np.array_equal(lu.perm_r, perm) or not np.array_equal(perm.reshape(-1, 3) % 3, np.tile(np.arange(3), (n, 1))) \
            or not np.array_equal(perm.reshape(-1, 3) // 3, np.repeat((perm[0::3] // 3)[:, None], 3, axis=1)):
        raise SimulationError("the rest system matrix could not be factored without pivoting")
    pivots = lu.U.diagonal()
    if not (np.all(np.isfinite(pivots)) and np.all(pivots > 0.0)):
        raise SimulationError("the rest system matrix is not positive definite")
    # lu.L is L (unit lower) of A_ordered[inv][:, inv]... with perm: rows/cols of A_ordered in perm order
    L = lu.L  # (CSC: its columns scaled in place of a product by a diagonal matrix, 3x faster)
    L = sp.csc_matrix((L.data * np.repeat(np.sqrt(pivots), np.diff(L.indptr)), L.indices, L.indptr),
                      shape=L.shape).tocsr()
    node_perm = perm[0::3] // 3
    Lb = sp.bsr_matrix(L, blocksize=(3, 3))
    Lb.sort_indices()
    row_of_block = np.repeat(np.arange(n), np.diff(Lb.indptr))
    diagonal = Lb.indices == row_of_block
    diag_blocks = np.zeros((n, 3, 3))
    diag_blocks[row_of_block[diagonal]] = Lb.data[diagonal]
    lower = Lb.indices < row_of_block
    counts = np.bincount(row_of_block[lower], minlength=n)
    row_start = np.concatenate([[0], np.cumsum(counts)])
    block_column = Lb.indices[lower].astype(np.int32)
    return BlockFactor(order=order[node_perm], row_start=row_start.astype(np.int32), block_column=block_column,
                       blocks=Lb.data[lower], diagonal_inverse=np.linalg.inv(diag_blocks),
                       subtrees=_subtree_split(row_start, block_column) if split else None)


def _subtree_split(row_start: np.ndarray, block_column: np.ndarray) -> tuple[int, int] | None:
    """``(a, b)`` of :class:`BlockFactor`: below the chain of rows at the top of the elimination
    tree (each the only child of the next), the subtrees of the first row with several
    children, in two groups of about equal work (blocks). The rows are in post-order (SuperLU
    post-orders the tree), so each subtree is a range of rows ending at its root; None when the
    tree does not branch or the ranges are not contiguous."""
    n = len(row_start) - 1
    rows = np.repeat(np.arange(n), np.diff(row_start))
    parent = np.full(n, n, dtype=np.int64)  # column J's parent: the first row below with a block in it
    np.minimum.at(parent, block_column, rows)
    size, work = np.ones(n + 1, dtype=np.int64), np.append(np.diff(row_start) + 1, 0)
    for j in range(n):  # children before parents in post-order
        size[parent[j]] += size[j]
        work[parent[j]] += work[j]
    node, kids = n, np.flatnonzero(parent == n)
    while len(kids) == 1:
        node, kids = kids[0], np.flatnonzero(parent == kids[0])
    if len(kids) < 2:
        return None
    starts, ends = kids - size[kids] + 1, kids + 1
    if starts[0] != 0 or np.any(starts[1:] != ends[:-1]) or ends[-1] != min(node, n):
        return None
    cumulative = np.cumsum(work[kids])
    split = int(np.argmin(np.maximum(cumulative[:-1], cumulative[-1] - cumulative[:-1])))
    return int(ends[split]), int(ends[-1])


# -- node rotations ----------------------------------------------------------------------------


def _owners(model) -> np.ndarray:
    """Per node, the index of the rotation it takes (-1: none): of its largest incident element,
    of equal ones the first (P1: the element; P2: element * 4 + the Gauss point nearest the
    node)."""
    cells, size = model.tet_indices.numpy(), model.tet_rest_volume.numpy()
    m, k = cells.shape
    nodes, element = cells.ravel(), np.repeat(np.arange(m), k)
    code = element
    if model.tet_order == 2:
        from . import p2

        points = np.concatenate([np.arange(4), p2.EDGES[:, 0]])  # corners, then an edge's first corner
        code = element * 4 + np.tile(points, m)
    largest = np.full(model.particle_count, -np.inf, dtype=size.dtype)
    np.maximum.at(largest, nodes, size[element])
    top = size[element] == largest[nodes]
    owner = np.full(model.particle_count, np.iinfo(np.int64).max)
    np.minimum.at(owner, nodes[top], code[top])  # (a smaller element has the smaller code)
    return np.where(largest > -np.inf, owner, -1).astype(np.int32)


# -- the preconditioner ------------------------------------------------------------------------


#: blocks of a factor from which its two subtrees are solved on two threads: a hand-over costs
#: about 0.1 ms, the solves about 18 ns per block (forward and backward), of which the two
#: subtrees of SOFA's 10x10x40 beam hold 74% (196k of 266k)
CONCURRENT_SOLVE_BLOCKS = 50000

#: CG iterations of a step beyond which a refresh in flight is taken at the next step (waiting
#: for it) instead of at its due step. A factor of the model's own converges in 1-7 iterations
#: (SOFA's beam at 0.1-10 MPa, the organ), the factor of before with the patch in 1-10 after
#: organ_cut's increments; after a complete cut of a 20k-element beam it needs 16-20 per step
#: (9 times the time of a step before), for the 79 steps its refresh is due after: the part cut
#: off falls freely, and the factor of before still holds it to the clamp
STRUGGLING_ITERATIONS = 12

#: the refresh's assembly and factorization time per block of the factor (s), measured 4-5 us
#: on the 2-core development machine (SOFA's 10x10x40 beam: 262k blocks in 1.1-1.3 s): a refresh
#: started after a change is taken that many seconds of simulated time later
REFRESH_SECONDS_PER_BLOCK = 5.0e-6


class RotatedCholesky:
    """The rotated rest factor of a model as a conjugate-gradient preconditioner (see the
    module's docstring), with its device arrays and its refresh.

    Args:
        model: the model whose system it preconditions.
        background: compute later factors (after a change, or of a new dt) on a background
            thread, the previous one serving meanwhile, and take them at the step by which a
            simulation running in real time would have them (:data:`REFRESH_SECONDS_PER_BLOCK`;
            the step is fixed when the refresh starts, so results do not depend on the
            machine's speed), or at the step after one the factor of before served badly
            (:data:`STRUGGLING_ITERATIONS`); False computes them at once and takes them at the
            next step.

    The first factor is computed by :meth:`update` at the first step (its dt is needed).
    """

    def __init__(self, model, *, background: bool = True):
        if not model.tet_count:
            raise SimulationError("the rotated Cholesky preconditioner is for tetrahedra; a shell uses 'jacobi'")
        self.model = model
        self.background = bool(background)
        n, d = model.particle_count, model.device
        self.node_rotation = wp.full(n, wp.quat_identity(), dtype=wp.quat, device=d)
        self.owner = wp.array(_owners(model), dtype=wp.int32, device=d)
        self.factor_rows = wp.full((n, 2), -1, dtype=wp.int32, device=d)
        self.factor_weights = wp.zeros((n, 2), dtype=wp.float32, device=d)
        self._factor: BlockFactor | None = None
        self._factored_for: tuple | None = None  # (dt, alpha, beta) of the factor in use
        self._arrays: tuple | None = None  # device arrays of the factor in use
        self.patch_position = wp.full(n, -1, dtype=wp.int32, device=d)
        self.patch_product = wp.zeros(n, dtype=wp.vec3, device=d)  # y = A x of the patch's products
        self._patch: tuple | None = None  # (factor, device arrays, nodes, elements around them) of the patch
        self._patch_due = False  # the patch is to be made (again) at the next update()
        self._pending: _Refresh | None = None
        self._outdated = False  # the factor in use is of the model before a change
        self._generation = 0  # bumped whenever the arrays the recorded launches use change
        self._steps = 0  # calls of update(): refreshes are taken at a step fixed when they start

    @property
    def generation(self) -> int:
        """Changes whenever the arrays of :meth:`record_apply` are replaced (record again)."""
        return self._generation

    @property
    def fallback_count(self) -> int:
        """Free nodes outside the factor of the whole model (nodes a change touched since it was
        computed; the patch serves them)."""
        return len(self._outside())

    @property
    def patch_count(self) -> int:
        """Nodes the patch serves: the free nodes outside the factor."""
        return 0 if self._patch is None else len(self._patch[0].order)

    def _outside(self) -> np.ndarray:
        rows = self.factor_rows.numpy()
        return np.flatnonzero((rows < 0).all(axis=1) & (self.model.particle_fixed.numpy() == 0))

    @property
    def refreshing(self) -> bool:
        """Whether a new factor is being computed."""
        return self._pending is not None

    def update(self, dt: float, struggling: bool = False) -> None:
        """Before a step of ``dt``: take a refresh that is due (waiting for it), or at once when
        the last step was ``struggling`` (needed more than :data:`STRUGGLING_ITERATIONS`); factor
        now if there is no factor yet; start a refresh if the factor is of another dt or
        damping, or of a model before a change."""
        m = self.model
        key = (dt, m.rayleigh_mass, m.rayleigh_stiffness)
        self._steps += 1
        if self._pending is not None and (self._steps >= self._pending.due_step or struggling
                                          or self._factor is None):
            pending, self._pending = self._pending, None
            self._adopt(*pending.result(), pending.positions, pending.key)
            self._outdated = pending.stale
        if self._factor is None:
            data = RestData.of(m)
            self._adopt(*_compute(data, key), _free_index(data), key)
            self._outdated = False
        if self._pending is None and (self._outdated or self._factored_for != key):
            self._start_refresh(key)
        if self._patch_due:
            self._make_patch()

    def wait(self) -> None:
        """Block until a refresh in flight is done (it is taken at the next :meth:`update`)."""
        if self._pending is not None:
            self._pending.join()

    def _start_refresh(self, key: tuple) -> None:
        data = RestData.of(self.model)
        delay = 1
        if self.background and self._factor is not None:  # the steps a real-time run takes meanwhile
            delay = max(1, int(np.ceil(REFRESH_SECONDS_PER_BLOCK * self._factor.block_count / key[0])))
        self._pending = _Refresh(data, key, _free_index(data), self.background, self._steps + delay)

    def _adopt(self, factor: BlockFactor, rows: np.ndarray, weights: np.ndarray, free_index: np.ndarray,
               key: tuple) -> None:
        """Use ``factor``, whose block rows and weights per free node of the factored model are
        ``rows`` and ``weights`` (:func:`_compute`); ``free_index`` (N,) maps the nodes to the
        factored model's free nodes (-1: outside the factor)."""
        d = self.model.device
        self._factor, self._factored_for = factor, key
        self._arrays = _device_arrays(factor, d)
        inside = (free_index >= 0)[:, None]
        at = np.where(inside[:, 0], free_index, 0)
        self.factor_rows.assign(np.where(inside, rows[at], -1).astype(np.int32))
        self.factor_weights.assign(np.where(inside, weights[at], 0.0).astype(np.float32))
        self._generation += 1
        self._patch_due = True

    def _make_patch(self) -> None:
        """The patch (see the module's docstring) of the nodes outside the factor, or none."""
        self._patch_due = False
        m, d = self.model, self.model.device
        outside = self._outside()
        positions = np.full(m.particle_count, -1, dtype=np.int32)
        self._patch = None
        if len(outside):
            patch = factor(rest_system_matrix(RestData.of(m), *self._factored_for, nodes=outside)[0], split=False)
            nodes = outside[patch.order]  # (in the patch's order)
            positions[nodes] = np.arange(len(nodes), dtype=np.int32)
            elements = np.flatnonzero((positions[m.tet_indices.numpy()] >= 0).any(axis=1))  # those around them
            self._patch = (patch, _device_arrays(patch, d), wp.array(nodes.astype(np.int32), device=d),
                           wp.array(elements.astype(np.int32), device=d))
        self.patch_position.assign(positions)
        self._generation += 1

    def carried(self, model, change) -> "RotatedCholesky":
        """This preconditioner for ``model``, made from this one's by ``change`` (a
        :class:`wcut.topology.TopologyChange`): the factor of before, with the vertices of the
        elements the change touched left out (a patch serves them from the next step), and a
        refresh of the factor started. This object must not be used afterwards."""
        out = RotatedCholesky.__new__(RotatedCholesky)
        out.model, out.background = model, self.background
        d = model.device
        out.node_rotation = wp.array(_carried_rotations(self.node_rotation.numpy(), change), dtype=wp.quat, device=d)
        out.owner = wp.array(_owners(model), dtype=wp.int32, device=d)
        out._factor, out._factored_for, out._arrays = self._factor, self._factored_for, self._arrays
        keep = _untouched(change, model)
        rows = _carried_positions(self.factor_rows.numpy(), keep)
        out.factor_rows = wp.array(rows, dtype=wp.int32, device=d)
        out.factor_weights = wp.array(np.where(rows >= 0, _carried_positions(self.factor_weights.numpy(), keep), 0.0),
                                      dtype=wp.float32, device=d)
        out.patch_position = wp.full(model.particle_count, -1, dtype=wp.int32, device=d)
        out.patch_product = wp.zeros(model.particle_count, dtype=wp.vec3, device=d)
        out._patch, out._patch_due = None, out._factor is not None
        out._generation, out._steps = self._generation + 1, self._steps
        out._outdated, out._pending = True, self._pending
        if out._pending is not None:  # its factor is of a model before this change: map it too
            out._pending.positions = _carried_positions(out._pending.positions, keep)
            out._pending.stale = True
        elif out._factored_for is not None:
            out._start_refresh(out._factored_for)
        return out

    # -- launches ------------------------------------------------------------------------------

    def launch_node_rotations(self, state) -> None:
        """``R_i`` of every node from the element rotations of the step (``state.tet_rotation``
        after the element pass)."""
        m = self.model
        kernel = cholesky.node_rotations_tet if m.tet_order == 1 else cholesky.node_rotations_gauss
        wp.launch(kernel, m.particle_count, device=m.device, inputs=[self.owner, state.tet_rotation],
                  outputs=[self.node_rotation])

    def concurrent(self, team) -> bool:
        """Whether :meth:`record_apply` with ``team`` solves two subtrees on two threads (its
        launches then cannot be captured in a graph)."""
        return (team is not None and team.size >= 2 and self._factor.subtrees is not None
                and self._factor.block_count >= CONCURRENT_SOLVE_BLOCKS and self.model.device.is_cpu)

    def record_apply(self, chunk: int, counter, inv_diagonal, r, z, rz, team=None, product=None) -> list:
        """The recorded launches of ``z = P^-1 r`` and ``rz[counter] = r.z``; the triangular
        solves of two subtrees (and the top rows' blocks in their columns) on two threads of
        ``team`` when :meth:`concurrent`.

        With a patch, ``P^-1`` is the symmetric multiplicative combination of the patch and the
        factor (see the module's docstring), which needs ``product(elements, nodes, x, y)``:
        the recorded launches of ``y += A x`` (A the system matrix, y zero before) from the
        listed elements, every spring and the mass of the listed nodes. With the patch's
        nodes and the elements around them, that is A x on the patch's rows, and on every row
        where x is zero outside the patch."""
        m, d = self.model, self.model.device
        row_start, block_column, blocks, diagonal_inverse, t, top_arrays = self._arrays
        node_threads = (m.particle_count + chunk - 1) // chunk
        if self._patch is not None and product is None:
            raise SimulationError("the preconditioner has a patch: its application needs the system's product")

        def forward(lo, hi):
            return wp.launch(cholesky.block_forward, 1, device=d, record_cmd=True,
                             inputs=[row_start, block_column, blocks, diagonal_inverse, lo, hi], outputs=[t])

        def backward(lo, hi, first_block=None):  # (rows lo..hi-1 from their first blocks)
            first_block = row_start[lo:hi] if first_block is None else first_block
            return wp.launch(cholesky.block_backward, 1, device=d, record_cmd=True,
                             inputs=[row_start, first_block, block_column, blocks, diagonal_inverse, lo], outputs=[t])

        n = len(self._factor.order)
        if self._factor.subtrees is not None:  # (the same sums on one thread or two: the same bits)
            a, b = self._factor.subtrees
            segments, sums = top_arrays

            def gather(k):  # the top rows' blocks in subtree k's columns, after its forward pass
                return wp.launch(cholesky.block_forward_gather, 1, device=d, record_cmd=True,
                                 inputs=[block_column, blocks, segments[k], segments[k + 1], t], outputs=[sums[k]])

            def scatter(k):  # and before its backward pass
                return wp.launch(cholesky.block_backward_scatter, 1, device=d, record_cmd=True,
                                 inputs=[block_column, blocks, segments[k], segments[k + 1], b], outputs=[t])

            together = _Concurrent if self.concurrent(team) else _Sequence
            solves = [together([_Sequence([forward(0, a), gather(0)]), _Sequence([forward(a, b), gather(1)])], team),
                      wp.launch(cholesky.block_forward_top, 1, device=d, record_cmd=True, outputs=[t],
                                inputs=[row_start, block_column, blocks, diagonal_inverse, segments[2], b, *sums]),
                      backward(b, n, first_block=segments[2]),
                      together([_Sequence([scatter(0), backward(0, a)]), _Sequence([scatter(1), backward(a, b)])], team)]
        else:
            solves = [forward(0, n), backward(0, n)]
        y = self.patch_product
        patch_t = t  # (unused without a patch)
        if self._patch is not None:
            patch, (patch_rows, patch_columns, patch_blocks, patch_diagonal, patch_t, _), nodes, elements = self._patch
            size = len(patch.order)

            def patch_solve(subtract: int) -> list:  # t_patch = A_S^-1 R^T (r - subtract y) on the patch
                return [wp.launch(cholesky.rotate_into_patch, size, device=d, record_cmd=True,
                                  inputs=[nodes, self.node_rotation, subtract, r, y], outputs=[patch_t]),
                        wp.launch(cholesky.block_forward, 1, device=d, record_cmd=True, outputs=[patch_t],
                                  inputs=[patch_rows, patch_columns, patch_blocks, patch_diagonal, 0, size]),
                        wp.launch(cholesky.block_backward, 1, device=d, record_cmd=True, outputs=[patch_t],
                                  inputs=[patch_rows, patch_rows[:-1], patch_columns, patch_blocks, patch_diagonal, 0])]

            def from_patch(correct: int):
                return wp.launch(cholesky.rotate_from_patch, size, device=d, record_cmd=True,
                                 inputs=[nodes, self.node_rotation, counter, correct, r, patch_t], outputs=[z, rz])

            # z1 = B_S r; the factor's part from r - A z1; then B_S of what is left on the patch
            z_product = [_MemsetLaunch(y), *product(elements, nodes, z, y)]  # y = A z
            before = [*patch_solve(0), _MemsetLaunch(z), from_patch(0), *z_product]
            after = [*z_product, *patch_solve(1), from_patch(1)]
        else:
            before, after = [], []
        return [
            *before,
            _MemsetLaunch(t),
            wp.launch(cholesky.rotate_into_factor, node_threads, device=d, record_cmd=True,
                      inputs=[chunk, int(self._patch is not None), self.factor_rows, self.factor_weights,
                              self.patch_position, self.node_rotation, r, y], outputs=[t]),
            *solves,
            wp.launch(cholesky.rotate_from_factor, node_threads, device=d, record_cmd=True,
                      inputs=[chunk, counter, int(m.tet_order == 2), self.factor_rows, self.factor_weights,
                              self.patch_position, self.node_rotation, inv_diagonal, r, t, patch_t], outputs=[z, rz]),
            *after,
        ]

    def apply(self, r: np.ndarray, inv_diagonal: np.ndarray | None = None, product=None) -> np.ndarray:
        """``P^-1 r`` for a host array (N, 3), with the current node rotations (for tests);
        ``product`` as :meth:`record_apply` takes it."""
        m, d = self.model, self.model.device
        if inv_diagonal is None:
            inv_diagonal = np.repeat(np.where(m.particle_fixed.numpy()[:, None] != 0, 0.0, 1.0), 3, axis=1)
        r_wp = wp.array(np.asarray(r, np.float32), dtype=wp.vec3, device=d)
        z = wp.zeros_like(r_wp)
        rz = wp.zeros(1, dtype=float, device=d)
        counter = wp.zeros(1, dtype=wp.int32, device=d)
        inv = wp.array(np.asarray(inv_diagonal, np.float32).reshape(-1, 3), dtype=wp.vec3, device=d)
        for cmd in self.record_apply(64, counter, inv, r_wp, z, rz, product=product):
            cmd.launch()
        return z.numpy().astype(np.float64)


def _device_arrays(factor: BlockFactor, device) -> tuple:
    """The arrays of ``factor`` that ``wcut.kernels.cholesky`` reads (float32), its right-hand
    side, and where it has two subtrees the top rows' segments (:func:`_top_segments`) and
    the sums of their blocks in each subtree's columns (else None)."""
    top = None
    if factor.subtrees is not None:
        top = ([wp.array(bounds, dtype=wp.int32, device=device) for bounds in _top_segments(factor)],
               [wp.zeros(len(factor.order) - factor.subtrees[1], dtype=wp.vec3, device=device) for _ in range(2)])
    return (wp.array(factor.row_start, dtype=wp.int32, device=device),
            wp.array(factor.block_column, dtype=wp.int32, device=device),
            wp.array(factor.blocks.astype(np.float32), dtype=wp.mat33, device=device),
            wp.array(factor.diagonal_inverse.astype(np.float32), dtype=wp.mat33, device=device),
            wp.zeros(len(factor.order), dtype=wp.vec3, device=device), top)


def _untouched(change, model) -> np.ndarray:
    """(N_after,) bool: vertices after ``change`` that are the vertex of the same index before and
    belong to no element the change added, reshaped or rewired, nor to one it removed (an
    element only renumbered, as a freed slot shifts the elements after it, changes no vertex's
    matrix). Where the change does not list its rewired elements and removed vertices, every
    element renumbered counts as changed."""
    from .model import _reparented, _touched_vertices

    n = change.vertex_count_after
    keep = np.zeros(n, dtype=bool)
    keep[:min(n, change.vertex_count_before)] = True
    keep[_touched_vertices(change)] = False
    if change.rewired_elements is not None and change.removed_vertices is not None:
        elements = [change.rest_changed_elements(), change.added_elements, change.rewired_elements]
        removed = change.removed_vertices
        keep[removed[removed < n]] = False
    else:
        parent = change.element_parent
        elements = [change.rest_changed_elements(), _reparented(change),
                    np.flatnonzero(parent != np.arange(len(parent)))]
    cells = model.tet_indices.numpy()
    changed = np.unique(np.concatenate(elements)).astype(np.int64)
    keep[cells[changed[changed < len(cells)]].ravel()] = False
    return keep


def _carried_positions(positions: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Per-node factor rows (N, ...) (or free indices (N,)) after a change: kept for the
    vertices it left untouched (``keep``, :func:`_untouched`), -1 for the others."""
    keep = keep.reshape((-1,) + (1,) * (positions.ndim - 1))
    out = np.full((len(keep),) + positions.shape[1:], -1, dtype=positions.dtype)
    k = min(len(positions), len(out))
    out[:k] = np.where(keep[:k], positions[:k], -1)
    return out


def _carried_rotations(rotations: np.ndarray, change) -> np.ndarray:
    """Node rotations (quaternions) after ``change``: each vertex takes the rotation of its
    first source vertex (the warm start of the next step's rotations)."""
    from .model import _touched_vertices

    n = change.vertex_count_after
    out = np.tile(np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32), (n, 1))
    k = min(n, len(rotations))
    out[:k] = rotations[:k]
    touched = _touched_vertices(change)
    if len(touched):
        sources, _ = change.vertex_rows(touched)
        out[touched] = rotations[sources[:, 0]]
    return out


def _top_segments(factor: BlockFactor) -> tuple:
    """Of the rows ``b..`` above the two subtrees (:attr:`BlockFactor.subtrees` ``(a, b)``): per
    row, where its blocks in the first subtree's columns start, where those in the second's
    start, and where those in the top rows' own columns start (a row's columns ascend)."""
    a, b = factor.subtrees
    n = len(factor.order)
    start = factor.row_start[b:n].astype(np.int64)
    columns = factor.block_column[start[0]:factor.row_start[n]] if n > b else np.zeros(0, np.int32)
    row = np.repeat(np.arange(n - b), np.diff(factor.row_start[b:n + 1]))
    below_a = np.bincount(row, weights=columns < a, minlength=n - b).astype(np.int64)
    below_b = np.bincount(row, weights=columns < b, minlength=n - b).astype(np.int64)
    return start, start + below_a, start + below_b


class _Sequence:
    """Recorded launches run one after another (a part of a :class:`_Concurrent`)."""

    def __init__(self, commands: list, team=None):
        self.commands, self.device = commands, commands[0].device

    def launch(self):
        for command in self.commands:
            command.launch()


class _Concurrent:
    """Recorded launches run at once on the threads of a ``wcut.split_launch.ThreadTeam`` (one
    after another inside a graph capture)."""

    def __init__(self, commands: list, team):
        self.team, self.commands = team, commands

    def launch(self):
        if self.commands[0].device.is_capturing:
            for command in self.commands:
                command.launch()
        else:
            self.team.run([command.launch for command in self.commands])


class _MemsetLaunch:
    """``array.zero_()`` in the list of recorded launches."""

    def __init__(self, array):
        self.array = array

    def launch(self):
        self.array.zero_()


def _compute(data: RestData, key: tuple) -> tuple:
    """The factor of ``data``'s rest system matrix (for quadratic elements, of its Galerkin
    projection ``Pi^T A0 Pi`` on the linear functions of the corners, :func:`_coarse_space`), and
    per free node of ``data`` the factor's block rows it is interpolated from (two, -1 for none)
    with their weights."""
    if any(part[0] == "tet" and part[1] == 2 for part in data.parts):
        A, Pi = coarse_system_matrix(data, *key)
    else:
        A, free = rest_system_matrix(data, *key)
        Pi = sp.identity(len(free), format="csr")
    F = factor(A)
    block_row = np.empty(len(F.order), dtype=np.int64)
    block_row[F.order] = np.arange(len(F.order))
    counts = np.diff(Pi.indptr)
    slot = np.arange(Pi.nnz) - np.repeat(Pi.indptr[:-1], counts)
    rows, weights = np.full((Pi.shape[0], 2), -1, dtype=np.int32), np.zeros((Pi.shape[0], 2), dtype=np.float32)
    at = np.repeat(np.arange(Pi.shape[0]), counts)
    rows[at, slot], weights[at, slot] = block_row[Pi.indices], Pi.data
    return F, rows, weights


def _free_index(data: RestData) -> np.ndarray:
    """The index of each node among the free nodes of ``data``'s model (-1: fixed)."""
    positions = np.full(data.node_count, -1, dtype=np.int64)
    free = np.flatnonzero(~data.fixed)
    positions[free] = np.arange(len(free))
    return positions


class _Refresh:
    """A factorization of a snapshot, on a background thread (or at once), to be taken at the
    step ``due_step`` (waiting for it if it is not done by then): a step fixed when it starts,
    so that results do not depend on the machine's speed."""

    def __init__(self, data: RestData, key: tuple, positions: np.ndarray, background: bool, due_step: int):
        self.key, self.positions, self.stale, self.due_step = key, positions, False, due_step
        self._result = self._error = None
        if background:
            self._thread = threading.Thread(target=self._run, args=(data,), daemon=True, name="wcut-factor")
            self._thread.start()
        else:
            self._thread = None
            self._run(data)

    def _run(self, data: RestData) -> None:
        try:
            self._result = _compute(data, self.key)
        except BaseException as error:  # noqa: BLE001 - re-raised on the caller's thread
            self._error = error

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join()

    def result(self) -> BlockFactor:
        self.join()
        if self._error is not None:
            raise self._error
        return self._result
