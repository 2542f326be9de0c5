"""Reference implicit step of corotational linear FEM in plain numpy + scipy.sparse.

This module is an *independent* implementation of one time step of the simulator, written the
way a scipy user would write it: assemble sparse matrices element by element (vectorised over
elements with numpy), then call :func:`scipy.sparse.linalg.cg` (or ``spsolve``). It shares no
code with the Warp kernels, so the tests can check those kernels against an assembled matrix,
and the benchmark uses it as the speed baseline.

Model (SI units throughout), linear tetrahedra:

* Rest shape matrix ``Dm = [X1-X0 | X2-X0 | X3-X0]`` (m), volume ``V = det(Dm)/6`` (m^3),
  constant shape-function gradients: rows of ``Dm^-1`` are ``grad N_1..N_3`` (1/m) and
  ``grad N_0 = -(grad N_1 + grad N_2 + grad N_3)``.
* Lame parameters ``mu = E / (2 (1 + nu))``, ``lambda = E nu / ((1 + nu)(1 - 2 nu))`` (Pa).
* Element stiffness (thesis eq. 3.48), 12x12 in N/m::

      K_e[3a+i, 3b+j] = V (lambda dN_b[j] dN_a[i] + mu delta_ij (dN_a . dN_b) + mu dN_b[i] dN_a[j])

* Element rotation ``R``: the closest proper rotation to ``F = Ds Dm^-1`` (polar decomposition
  through a batched SVD, the sign of the column of ``U`` of the smallest singular value flipped
  when ``det(U V^T) < 0``).
* Corotational force ``f_e = -R_e K_e (R_e^T x_e - X_e)`` (N) and corotational stiffness
  ``K(x) = sum_e R_e K_e R_e^T`` (thesis eq. 3.49), ``R_e`` = four diagonal copies of ``R``.
* Lumped mass ``m_i = sum_{e owns i} rho_e V_e / 4`` (kg), Rayleigh damping
  ``D = alpha M + beta K(x)`` (thesis eq. 3.52; ``alpha`` in 1/s, ``beta`` in s).
* Barycentric springs: point ``p_s = sum_j w_sj x_j``, energy ``1/2 k_s |p_s - t_s|^2``
  (``k_s`` in N/m), stiffness ``K_S = sum_s k_s (w_s w_s^T) (x) I_3``.
* One implicit Euler step with one Newton iteration (thesis eq. 3.69, Baraff-Witkin form),
  ``h = dt`` (s)::

      A  = (1 + h alpha) M + (h^2 + h beta) K(x) + h^2 K_S
      b  = h (f_int(x) + f_ext + M g + f_spring(x) - alpha M v) - (h^2 + h beta) K(x) v - h^2 K_S v
      A dv = b  on the free degrees of freedom;  v' = v + dv,  x' = x + h v'

Degrees of freedom are ordered ``3 * node + component`` everywhere.
"""

from __future__ import annotations

import numpy as np
import scipy
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import MeshError, SimulationError, WcutError

__all__ = ["ScipyCorotationalStep", "lame_parameters"]


def lame_parameters(youngs_modulus, poisson_ratio):
    """Return ``(mu, lambda)`` in Pa from Young's modulus ``E`` (Pa) and Poisson ratio ``nu``."""
    E = np.asarray(youngs_modulus, dtype=np.float64)
    nu = np.asarray(poisson_ratio, dtype=np.float64)
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def _scipy_uses_rtol() -> bool:
    """scipy >= 1.12 names the relative CG tolerance ``rtol`` (``tol`` before)."""
    try:
        major, minor = (int(p) for p in scipy.__version__.split(".")[:2])
    except ValueError:  # pragma: no cover - exotic version strings
        return True
    return (major, minor) >= (1, 12)


_CG_USES_RTOL = _scipy_uses_rtol()


def _finite_array(value, name, shape=None, dtype=np.float64):
    """Convert ``value`` to a float array, check its shape (``None`` entries are free) and finiteness."""
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise WcutError(f"{name} must be a numeric array: {exc}") from None
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, arr.shape))
        if not ok:
            want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
            raise WcutError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise WcutError(f"{name} contains a non-finite value at index {tuple(int(i) for i in bad)}")
    return arr


def _index_array(value, name, n_vertices, ndim):
    """Convert ``value`` to an int64 index array of ``ndim`` dims with entries in ``[0, n_vertices)``."""
    arr = np.asarray(value)
    if arr.size == 0:
        arr = arr.astype(np.int64)
    if arr.dtype.kind not in "iu":
        raise WcutError(f"{name} must be an integer array, got dtype {arr.dtype}")
    if arr.ndim != ndim:
        raise WcutError(f"{name} must be {ndim}-dimensional, got shape {arr.shape}")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= n_vertices):
        raise WcutError(f"{name} has indices outside [0, {n_vertices}): min {arr.min()}, max {arr.max()}")
    return arr


def _per_element(value, name, n_elements):
    """A material parameter given as a scalar or an ``(M,)`` array, returned as ``(M,)`` float64."""
    arr = _finite_array(value, name)
    if arr.ndim == 0:
        return np.full(n_elements, float(arr))
    if arr.shape != (n_elements,):
        raise WcutError(f"{name} must be a scalar or have shape ({n_elements},), got {arr.shape}")
    return arr.copy()


def _symmetric_factor(K: sp.csc_matrix) -> "_OrderedFactor":
    """SuperLU's factor of a symmetric positive definite matrix of 3-vectors, on a nested
    dissection order of its nodes (SuperLU's own orders fill in far more on 3-D meshes: minutes
    for 66k unknowns): ``solve(b)`` solves ``K x = b``."""
    from .preconditioner import nested_dissection

    order = nested_dissection(K[0::3, 0::3] != 0)
    dofs = (3 * order[:, None] + np.arange(3)).ravel()
    lu = spla.splu(K[dofs][:, dofs].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                   options=dict(SymmetricMode=True))
    return _OrderedFactor(lu, dofs)


class _OrderedFactor:
    """A factor of ``K`` permuted by ``dofs``. A plain object: a class made per call (with its
    closure) is a reference cycle, and its gigabytes of native factor waited for Python's cycle
    collector while Newton's method made the next one."""

    def __init__(self, lu, dofs: np.ndarray):
        self.lu, self.dofs = lu, dofs

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = np.empty_like(b)
        x[self.dofs] = self.lu.solve(b[self.dofs])
        return x


#: Relative residual at which :meth:`ScipyCorotationalStep.static_equilibrium` ends an
#: intermediate load increment (only the whole load needs the final tolerance).
INCREMENT_TOLERANCE = 1e-3
#: The smallest load increment (a fraction of the load) static equilibrium tries.
SMALLEST_INCREMENT = 1.0 / 4096


class ScipyCorotationalStep:
    """One implicit step of corotational linear FEM, assembled with scipy.sparse.

    Parameters
    ----------
    rest_positions : (N, 3) float
        Rest positions ``X`` in m.
    tets : (M, 4) int
        Tetrahedra, positively oriented (``det[X1-X0, X2-X0, X3-X0] > 0``).
    density : float or (M,) float
        Mass density ``rho`` in kg/m^3.
    youngs_modulus : float or (M,) float
        Young's modulus ``E`` in Pa.
    poisson_ratio : float or (M,) float
        Poisson ratio ``nu`` (dimensionless, ``-1 < nu < 0.5``).
    rayleigh_mass : float
        Rayleigh mass coefficient ``alpha`` in 1/s (thesis eq. 3.52).
    rayleigh_stiffness : float
        Rayleigh stiffness coefficient ``beta`` in s (thesis eq. 3.52).
    gravity : (3,) float
        Gravitational acceleration ``g`` in m/s^2.
    fixed : None, (N,) bool mask or 1-D int index array
        Dirichlet vertices: their velocity is zero and their position never changes.
    spring_indices : (S, K) int, 1 <= K <= 4
        Vertices of each barycentric spring (unused slots: any valid index with weight 0).
    spring_weights : (S, K) float
        Barycentric weights ``w_sj`` (dimensionless).
    spring_stiffness : (S,) float
        Spring stiffness ``k_s`` in N/m.
    rotation_stiffness : bool
        Add to ``K(x)`` the stiffness of the rotation's variation, projected to its tension part
        (see :meth:`rotation_stiffness_matrix`), as ``wcut.SolverCorotational`` does by default.
        False (the default here): the thesis's ``sum_e R_e K_e R_e^T``.

    Attributes
    ----------
    masses : (N,) float
        Lumped vertex masses in kg.
    volumes : (M,) float
        Rest volumes in m^3.
    shape_gradients : (M, 4, 3) float
        Constant shape-function gradients ``grad N_a`` in 1/m.
    fixed : (N,) bool
        Dirichlet mask.
    last_cg_info : int or None
        ``info`` returned by the last CG solve (0: converged to ``cg_tolerance``;
        > 0: stopped at ``cg_iterations``); ``None`` after a direct solve.
    last_cg_iterations : int or None
        Number of CG iterations done by the last iterative solve.
    """

    def __init__(
        self,
        rest_positions,
        tets,
        *,
        density,
        youngs_modulus,
        poisson_ratio,
        rayleigh_mass=0.0,
        rayleigh_stiffness=0.0,
        gravity=(0.0, 0.0, 0.0),
        fixed=None,
        spring_indices=None,
        spring_weights=None,
        spring_stiffness=None,
        rotation_stiffness=False,
    ):
        self.rotation_stiffness = bool(rotation_stiffness)
        X = _finite_array(rest_positions, "rest_positions", (None, 3))
        n = X.shape[0]
        if n == 0:
            raise MeshError("rest_positions is empty")
        T = _index_array(tets, "tets", n, 2)
        if T.shape[1] != 4:
            raise MeshError(f"tets must have shape (M, 4), got {T.shape}")
        m_el = T.shape[0]
        if m_el == 0:
            raise MeshError("tets is empty")

        self.rest_positions = X.copy()
        self.tets = T
        self.n_vertices = n
        self.n_elements = m_el

        # --- materials -----------------------------------------------------------------
        self.density = _per_element(density, "density", m_el)
        self.youngs_modulus = _per_element(youngs_modulus, "youngs_modulus", m_el)
        self.poisson_ratio = _per_element(poisson_ratio, "poisson_ratio", m_el)
        if np.any(self.density <= 0):
            raise WcutError(f"density must be > 0 kg/m^3 (element {int(np.argmax(self.density <= 0))})")
        if np.any(self.youngs_modulus <= 0):
            raise WcutError(
                f"youngs_modulus must be > 0 Pa (element {int(np.argmax(self.youngs_modulus <= 0))})"
            )
        bad_nu = (self.poisson_ratio <= -1.0) | (self.poisson_ratio >= 0.5)
        if np.any(bad_nu):
            raise WcutError(f"poisson_ratio must lie in (-1, 0.5) (element {int(np.argmax(bad_nu))})")
        self.mu, self.lam = lame_parameters(self.youngs_modulus, self.poisson_ratio)

        self.rayleigh_mass = float(_finite_array(rayleigh_mass, "rayleigh_mass", ()))
        self.rayleigh_stiffness = float(_finite_array(rayleigh_stiffness, "rayleigh_stiffness", ()))
        if self.rayleigh_mass < 0 or self.rayleigh_stiffness < 0:
            raise WcutError("rayleigh_mass and rayleigh_stiffness must be >= 0")
        self.gravity = _finite_array(gravity, "gravity", (3,)).copy()

        # --- geometry: Dm, volumes, shape gradients ---------------------------------------
        Xe = X[T]  # (M, 4, 3)
        Dm = np.transpose(Xe[:, 1:, :] - Xe[:, :1, :], (0, 2, 1))  # columns X_k - X_0
        det = np.linalg.det(Dm)
        vol = det / 6.0
        if not np.all(vol > 0):
            bad = int(np.argmax(~(vol > 0)))
            raise MeshError(
                f"tet {bad} (vertices {T[bad].tolist()}) has non-positive volume {vol[bad]:.3e} m^3; "
                "tets must be non-degenerate and positively oriented"
            )
        Dm_inv = np.linalg.inv(Dm)
        grads = np.empty((m_el, 4, 3))
        grads[:, 1:, :] = Dm_inv  # rows of Dm^-1
        grads[:, 0, :] = -Dm_inv.sum(axis=1)
        self.Dm_inv = Dm_inv
        self.volumes = vol
        self.shape_gradients = grads

        # --- lumped masses -------------------------------------------------------------
        quarter = np.repeat(self.density * vol / 4.0, 4)
        self.masses = np.bincount(T.ravel(), weights=quarter, minlength=n)

        # --- Dirichlet vertices --------------------------------------------------------
        mask = np.zeros(n, dtype=bool)
        if fixed is not None:
            f = np.asarray(fixed)
            if f.dtype == bool:
                if f.shape != (n,):
                    raise WcutError(f"fixed as a boolean mask must have shape ({n},), got {f.shape}")
                mask = f.copy()
            else:
                idx = _index_array(f.ravel() if f.ndim == 0 else f, "fixed", n, 1)
                mask[idx] = True
        self.fixed = mask
        orphans = (self.masses <= 0) & ~mask
        if np.any(orphans):
            raise MeshError(
                f"{int(orphans.sum())} free vertices belong to no tet (first: {int(np.argmax(orphans))}); "
                "remove them or fix them"
            )

        # --- sparse pattern: dof indices of each element ---------------------------------
        self._elem_dofs = (3 * T[:, :, None] + np.arange(3)).reshape(m_el, 12)  # (M, 12)
        idx_dtype = np.int32 if 3 * n < np.iinfo(np.int32).max else np.int64
        self._coo_rows = np.broadcast_to(self._elem_dofs[:, :, None], (m_el, 12, 12)).ravel().astype(idx_dtype)
        self._coo_cols = np.broadcast_to(self._elem_dofs[:, None, :], (m_el, 12, 12)).ravel().astype(idx_dtype)
        self._Ke = None

        # --- springs ---------------------------------------------------------------------
        given = [a is not None for a in (spring_indices, spring_weights, spring_stiffness)]
        if any(given) and not all(given):
            raise WcutError("spring_indices, spring_weights and spring_stiffness must be given together")
        if all(given):
            si = _index_array(spring_indices, "spring_indices", n, 2)
            if not 1 <= si.shape[1] <= 4:
                raise WcutError(f"spring_indices must have shape (S, K) with 1 <= K <= 4, got {si.shape}")
            sw = _finite_array(spring_weights, "spring_weights", si.shape)
            sk = _finite_array(spring_stiffness, "spring_stiffness", (si.shape[0],))
            if np.any(sk < 0):
                raise WcutError("spring_stiffness must be >= 0 N/m")
        else:
            si = np.zeros((0, 4), dtype=np.int64)
            sw = np.zeros((0, 4))
            sk = np.zeros(0)
        self.spring_indices = si
        self.spring_weights = sw
        self.spring_stiffness = sk
        self._KS = None

        self.last_cg_info = None
        self.last_cg_iterations = None

    # ------------------------------------------------------------------------------------
    # small helpers
    @property
    def n_springs(self) -> int:
        return int(self.spring_indices.shape[0])

    def _positions(self, x, name="x"):
        return _finite_array(x, name, (self.n_vertices, 3))

    def _assemble(self, blocks):
        """Sum ``(M, 12, 12)`` element blocks into a ``(3N, 3N)`` CSR matrix (duplicates added)."""
        ndof = 3 * self.n_vertices
        coo = sp.coo_matrix((blocks.ravel(), (self._coo_rows, self._coo_cols)), shape=(ndof, ndof))
        return coo.tocsr()

    def _scatter(self, elem_vectors):
        """Sum ``(M, 4, 3)`` per-element nodal vectors into an ``(N, 3)`` array."""
        flat = np.bincount(
            self._elem_dofs.ravel(), weights=elem_vectors.reshape(-1), minlength=3 * self.n_vertices
        )
        return flat.reshape(self.n_vertices, 3)

    # ------------------------------------------------------------------------------------
    # element quantities
    def element_stiffness(self) -> np.ndarray:
        """Rest element stiffness matrices ``K_e`` (thesis eq. 3.48), shape (M, 12, 12), N/m.

        ``K_e[3a+i, 3b+j] = V (lambda dN_b[j] dN_a[i] + mu delta_ij dN_a.dN_b + mu dN_b[i] dN_a[j])``.
        Computed once and cached; the returned array is read-only.
        """
        if self._Ke is None:
            G = self.shape_gradients  # (M, 4, 3): G[m, a, i] = dN_a[i]
            V = self.volumes[:, None, None, None, None]
            lam = self.lam[:, None, None, None, None]
            mu = self.mu[:, None, None, None, None]
            # index order of the 5-d block: [m, a, i, b, j]
            term_lam = np.einsum("mai,mbj->maibj", G, G)  # dN_a[i] dN_b[j]
            term_mu_t = np.einsum("maj,mbi->maibj", G, G)  # dN_a[j] dN_b[i]
            dots = np.einsum("mak,mbk->mab", G, G)  # dN_a . dN_b
            term_mu_d = dots[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
            Ke = V * (lam * term_lam + mu * term_mu_d + mu * term_mu_t)
            Ke = Ke.reshape(self.n_elements, 12, 12)
            Ke.setflags(write=False)
            self._Ke = Ke
        return self._Ke

    def rotations(self, x) -> np.ndarray:
        """Per-element rotations ``R`` (M, 3, 3): polar decomposition of ``F = Ds Dm^-1``.

        Uses numpy's batched SVD ``F = U S V^T``; when ``det(U V^T) < 0`` the column of ``U`` that
        belongs to the smallest singular value (the last one) is negated, so ``R = U V^T`` is a
        proper rotation (det +1) also for inverted elements.
        """
        x = self._positions(x)
        return self._rotations(x)

    def _rotations(self, x):
        xe = x[self.tets]
        Ds = np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1))
        F = Ds @ self.Dm_inv
        U, _, Vt = np.linalg.svd(F)
        R = U @ Vt
        neg = np.linalg.det(R) < 0
        if np.any(neg):
            U[neg, :, 2] *= -1.0
            R[neg] = U[neg] @ Vt[neg]
        return R

    def _internal_forces(self, x, R):
        Ke = self.element_stiffness()
        xe = x[self.tets]  # (M, 4, 3), rows are nodal positions
        Xe = self.rest_positions[self.tets]
        d = xe @ R - Xe  # row a is R^T x_a - X_a
        Kd = (Ke @ d.reshape(self.n_elements, 12, 1)).reshape(self.n_elements, 4, 3)
        fe = -(Kd @ np.transpose(R, (0, 2, 1)))  # row a is -R (K d)_a
        return self._scatter(fe)

    def internal_forces(self, x) -> np.ndarray:
        """Corotational elastic forces ``f_int`` (N, 3) in N.

        ``f_e = -R_e K_e (R_e^T x_e - X_e)`` per element (thesis eqs. 3.48-3.49), summed over
        elements. With the polar rotation this is exactly ``-dE/dx`` of the corotational energy
        ``E = 1/2 sum_e (R_e^T x_e - X_e)^T K_e (R_e^T x_e - X_e)``.
        """
        x = self._positions(x)
        return self._internal_forces(x, self._rotations(x))

    def _stiffness_matrix(self, x, R):
        m = self.n_elements
        Ke = self.element_stiffness()
        # view as 16 3x3 blocks K_ab, rotate each: R K_ab R^T
        blocks = Ke.reshape(m, 4, 3, 4, 3).transpose(0, 1, 3, 2, 4)  # [m, a, b, i, j]
        Rb = R[:, None, None, :, :]
        rotated = Rb @ blocks @ np.transpose(Rb, (0, 1, 2, 4, 3))
        if self.rotation_stiffness:
            rotated = rotated + self._rotation_stiffness_blocks(x, R)
        rotated = rotated.transpose(0, 1, 3, 2, 4).reshape(m, 12, 12)
        return self._assemble(rotated)

    def _rotation_stiffness_blocks(self, x, R):
        """Blocks ``[m, a, b]`` (3x3, N/m) of the projected rotation stiffness of each element:
        ``V/2 [r_a]_x^T G_w [r_b]_x`` with ``r_a = R grad N_a``.

        ``G`` (Pa) comes from the stretch ``S = R^T F`` through its eigen-decomposition (SVD of
        F): eigenvalues ``g_i = 2 mu + 2 c / (tr S - s_i)`` with ``c = lambda tr(S - I) - 2 mu``,
        the exact term ``R [G axial(skew(R^T dF))]_x`` that ``R K R^T`` leaves out of
        ``dP``. Projection: all ``g_i >= 0``: kept; all ``<= 0``: zero; else the chord
        ``g_max (g_i - g_min) / (g_max - g_min)``.
        """
        xe = x[self.tets]
        F = np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1)) @ self.Dm_inv
        S = np.transpose(R, (0, 2, 1)) @ F
        s, vectors = np.linalg.eigh(0.5 * (S + np.transpose(S, (0, 2, 1))))
        tr = s.sum(axis=1, keepdims=True)
        c = (self.lam * (tr[:, 0] - 3.0) - 2.0 * self.mu)[:, None]
        m_i = tr - s
        g = 2.0 * self.mu[:, None] + 2.0 * c / np.where(m_i > 0, m_i, 1.0)
        low, high = g.min(axis=1, keepdims=True), g.max(axis=1, keepdims=True)
        chord = high * (g - low) / np.where(high > low, high - low, 1.0)
        g = np.where(low >= 0, g, np.where(high <= 0, 0.0, chord))
        g[(m_i <= 1e-3 * np.abs(tr)).any(axis=1)] = 0.0
        G = np.einsum("mij,mj,mkj->mik", R @ vectors, g, R @ vectors) * self.volumes[:, None, None]
        r = self.shape_gradients @ np.transpose(R, (0, 2, 1))  # [m, a] = R grad N_a
        cross = np.zeros(r.shape + (3,))  # [m, a] = [r_a]_x
        cross[..., 0, 1], cross[..., 0, 2], cross[..., 1, 2] = -r[..., 2], r[..., 1], -r[..., 0]
        cross[..., 1, 0], cross[..., 2, 0], cross[..., 2, 1] = r[..., 2], -r[..., 1], r[..., 0]
        return 0.5 * np.einsum("maji,mjk,mbkl->mabil", cross, G, cross)

    def stiffness_matrix(self, x) -> sp.csr_matrix:
        """Corotational stiffness ``K(x) = sum_e R_e K_e R_e^T`` (thesis eq. 3.49), (3N, 3N) CSR,
        N/m, plus the rotation stiffness when the reference was made with ``rotation_stiffness``."""
        x = self._positions(x)
        return self._stiffness_matrix(x, self._rotations(x))

    def spring_matrix(self) -> sp.csr_matrix:
        """Spring stiffness ``K_S = sum_s k_s (w_s w_s^T) (x) I_3``, (3N, 3N) CSR in N/m (cached)."""
        if self._KS is None:
            ndof = 3 * self.n_vertices
            if self.n_springs == 0:
                self._KS = sp.csr_matrix((ndof, ndof))
            else:
                si, sw, sk = self.spring_indices, self.spring_weights, self.spring_stiffness
                s, k = si.shape
                vals = sk[:, None, None] * sw[:, :, None] * sw[:, None, :]  # (S, K, K)
                vals = np.broadcast_to(vals[..., None], (s, k, k, 3))
                c = np.arange(3)
                rows = np.broadcast_to(3 * si[:, :, None, None] + c, (s, k, k, 3))
                cols = np.broadcast_to(3 * si[:, None, :, None] + c, (s, k, k, 3))
                self._KS = sp.coo_matrix(
                    (vals.ravel(), (rows.ravel(), cols.ravel())), shape=(ndof, ndof)
                ).tocsr()
        return self._KS

    def spring_forces(self, x, spring_targets) -> np.ndarray:
        """Spring forces (N, 3) in N: vertex ``j`` of spring ``s`` gets ``-k_s w_sj (p_s - t_s)``."""
        x = self._positions(x)
        return self._spring_forces(x, spring_targets)

    def _spring_forces(self, x, spring_targets):
        if self.n_springs == 0:
            return np.zeros((self.n_vertices, 3))
        if spring_targets is None:
            raise WcutError(f"{self.n_springs} springs are defined but spring_targets was not given")
        t = _finite_array(spring_targets, "spring_targets", (self.n_springs, 3))
        si, sw, sk = self.spring_indices, self.spring_weights, self.spring_stiffness
        p = np.einsum("sk,skc->sc", sw, x[si])  # (S, 3) attachment points
        fs = -(sk[:, None, None] * sw[:, :, None]) * (p - t)[:, None, :]  # (S, K, 3)
        out = np.zeros((self.n_vertices, 3))
        np.add.at(out, si.ravel(), fs.reshape(-1, 3))
        return out

    # ------------------------------------------------------------------------------------
    # the implicit system (thesis eq. 3.69)
    def _check_dt(self, dt):
        dt = float(_finite_array(dt, "dt", ()))
        if dt <= 0:
            raise WcutError(f"dt must be > 0 s, got {dt}")
        return dt

    def _system_matrix(self, K, dt):
        h, a, b = dt, self.rayleigh_mass, self.rayleigh_stiffness
        Mdiag = sp.diags(np.repeat(self.masses, 3) * (1.0 + h * a), format="csr")
        A = Mdiag + (h * h + h * b) * K
        if self.n_springs:
            A = A + (h * h) * self.spring_matrix()
        return A.tocsr()

    def system_matrix(self, x, dt) -> sp.csr_matrix:
        """``A = (1 + h alpha) M + (h^2 + h beta) K(x) + h^2 K_S`` (thesis eqs. 3.52, 3.69), kg.

        Full size (3N, 3N) CSR; the rows and columns of fixed vertices are *not* removed.
        """
        x = self._positions(x)
        dt = self._check_dt(dt)
        return self._system_matrix(self._stiffness_matrix(x, self._rotations(x)), dt)

    def _rhs(self, x, v, dt, f_ext, spring_targets, R, K):
        h, a, b = dt, self.rayleigh_mass, self.rayleigh_stiffness
        m = self.masses[:, None]
        force = self._internal_forces(x, R) + m * self.gravity[None, :] - a * m * v
        if f_ext is not None:
            force = force + _finite_array(f_ext, "f_ext", (self.n_vertices, 3))
        if self.n_springs:
            force = force + self._spring_forces(x, spring_targets)
        vf = v.reshape(-1)
        rhs = h * force.reshape(-1) - (h * h + h * b) * (K @ vf)
        if self.n_springs:
            rhs -= (h * h) * (self.spring_matrix() @ vf)
        return rhs.reshape(self.n_vertices, 3)

    def rhs(self, x, v, dt, f_ext=None, spring_targets=None) -> np.ndarray:
        """Right-hand side ``b`` of thesis eq. 3.69, (N, 3) in N s (= kg m/s).

        ``b = h (f_int(x) + f_ext + M g + f_spring(x) - alpha M v) - (h^2 + h beta) K(x) v - h^2 K_S v``.
        ``v`` is used as given (including at fixed vertices); entries at fixed vertices are not zeroed.
        """
        x = self._positions(x)
        v = _finite_array(v, "v", (self.n_vertices, 3))
        dt = self._check_dt(dt)
        R = self._rotations(x)
        return self._rhs(x, v, dt, f_ext, spring_targets, R, self._stiffness_matrix(x, R))

    def static_equilibrium(self, f_ext=None, *, load_steps: int = 1, tolerance: float = 1e-7,
                           max_iterations: int = 60) -> np.ndarray:
        """Positions (N, 3) in m where the corotational elastic forces balance gravity and
        ``f_ext``: Newton's method with direct solves on the free degrees of freedom, the load
        applied in increments (continuation): the first is ``1 / load_steps`` of it; an
        increment that does not converge is undone and retried at a quarter of its size, one
        that converges quickly doubles the next. Intermediate increments stop at a relative
        residual of :data:`INCREMENT_TOLERANCE`, the whole load at ``tolerance`` times the
        load. The tangent is ``sum R K R^T`` plus the projected rotation stiffness, factored
        again only when an iteration reduces the residual by less than a factor 4 (modified
        Newton). Raises :class:`SimulationError` when the increments become smaller than
        :data:`SMALLEST_INCREMENT` of the load."""
        load = self.masses[:, None] * self.gravity[None, :]
        if f_ext is not None:
            load = load + _finite_array(f_ext, "f_ext", (self.n_vertices, 3))
        free = np.repeat(~self.fixed, 3)
        scale = np.abs(load.reshape(-1)[free]).max(initial=0.0)
        x = self.rest_positions.copy()
        if scale == 0.0:
            return x
        tangent = ScipyCorotationalStep.__new__(ScipyCorotationalStep)
        tangent.__dict__.update(self.__dict__)
        tangent.rotation_stiffness = True
        fraction, step = 0.0, 1.0 / load_steps
        while fraction < 1.0:
            goal = min(1.0, fraction + step)
            limit = (tolerance if goal == 1.0 else INCREMENT_TOLERANCE) * scale
            start, factor, last, growing = x.copy(), None, np.inf, 0
            for iteration in range(max_iterations):
                R = self._rotations(x)
                residual = (self._internal_forces(x, R) + goal * load).reshape(-1)[free]
                size = np.abs(residual).max()
                if size <= limit or not np.isfinite(size):
                    break
                growing = growing + 1 if size > last else 0
                if growing >= 3:  # diverging: a smaller increment
                    break
                if factor is None or size > 0.25 * last:  # (modified Newton: refactor when it slows)
                    factor = _symmetric_factor(tangent._stiffness_matrix(x, R)[free][:, free].tocsc())
                last = size
                dx = np.zeros(3 * self.n_vertices)
                dx[free] = factor.solve(residual)
                x = x + dx.reshape(-1, 3)
            if size <= limit:
                fraction = goal
                step = 2.0 * step if iteration < 6 else step
                continue
            x, step = start, 0.25 * step
            if step < SMALLEST_INCREMENT:
                raise SimulationError(f"static equilibrium: at {100 * fraction:.3g}% of the load, no increment down "
                                      f"to {SMALLEST_INCREMENT:g} of it converged in {max_iterations} Newton iterations")
        return x

    def step(
        self,
        x,
        v,
        dt,
        *,
        f_ext=None,
        spring_targets=None,
        cg_iterations=20,
        cg_tolerance=1e-8,
        direct=False,
        dv0=None,
    ):
        """Advance one implicit Euler step (one Newton iteration, thesis eq. 3.69).

        Parameters
        ----------
        x, v : (N, 3)
            Positions (m) and velocities (m/s). The velocity of fixed vertices is taken as zero.
        dt : float
            Time step ``h`` in s.
        f_ext : (N, 3), optional
            External nodal forces in N.
        spring_targets : (S, 3), optional
            Spring targets ``t_s`` in m (required when springs are defined).
        cg_iterations, cg_tolerance
            ``maxiter`` and relative tolerance of :func:`scipy.sparse.linalg.cg` (Jacobi
            preconditioned, ``atol = 0``). Not reaching the tolerance is not an error; see
            :attr:`last_cg_info`.
        direct : bool
            Solve exactly with :func:`scipy.sparse.linalg.spsolve` instead of CG.
        dv0 : (N, 3), optional
            Initial guess of ``dv`` for CG (zeros by default).

        Returns
        -------
        x_new, v_new : (N, 3)
            ``v_new = v + dv`` (0 at fixed vertices), ``x_new = x + h v_new`` (``x`` at fixed vertices).
        """
        x = self._positions(x)
        v = _finite_array(v, "v", (self.n_vertices, 3)).copy()
        dt = self._check_dt(dt)
        v[self.fixed] = 0.0

        R = self._rotations(x)
        K = self._stiffness_matrix(x, R)
        A = self._system_matrix(K, dt)
        b = self._rhs(x, v, dt, f_ext, spring_targets, R, K).reshape(-1)

        free = np.flatnonzero(np.repeat(~self.fixed, 3))
        dv = np.zeros(3 * self.n_vertices)
        if free.size:
            A_ff = A[free][:, free]
            b_f = b[free]
            if direct:
                dv[free] = spla.spsolve(A_ff.tocsc(), b_f)
                self.last_cg_info = None
                self.last_cg_iterations = None
            else:
                if dv0 is None:
                    x0 = np.zeros(free.size)
                else:
                    x0 = _finite_array(dv0, "dv0", (self.n_vertices, 3)).reshape(-1)[free]
                jacobi = sp.diags(1.0 / A_ff.diagonal(), format="csr")
                count = [0]

                def _count(_xk):
                    count[0] += 1

                tol_kw = {"rtol": cg_tolerance} if _CG_USES_RTOL else {"tol": cg_tolerance}
                sol, info = spla.cg(
                    A_ff, b_f, x0=x0, maxiter=int(cg_iterations), M=jacobi, atol=0.0,
                    callback=_count, **tol_kw,
                )
                if info < 0:
                    raise SimulationError(f"scipy CG failed with info={info}")
                dv[free] = sol
                self.last_cg_info = int(info)
                self.last_cg_iterations = count[0]
        if not np.all(np.isfinite(dv)):
            raise SimulationError("the implicit step produced non-finite velocities (diverged)")

        v_new = v + dv.reshape(self.n_vertices, 3)
        v_new[self.fixed] = 0.0
        x_new = x + dt * v_new
        x_new[self.fixed] = x[self.fixed]
        return x_new, v_new
