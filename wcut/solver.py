"""Implicit corotational solver: one Newton step of implicit Euler per time step.

:class:`SolverCorotational` only orchestrates launches of the kernels in ``wcut.kernels``;
it owns the scratch arrays of the step, allocated once in the constructor. A step
(thesis eq. 3.69) is:

1. per element: polar rotation (warm-started), rotated shape gradients, corotational force,
   the stiffness part of the right-hand side, the stiffness diagonal;
2. per attachment: force and diagonal;
3. per node: right-hand side ``b``, the diagonal D of A, and the node rotations of the
   preconditioner;
4. preconditioned conjugate gradient on ``A dv = b`` from ``dv = 0``, until the relative
   Jacobi-scaled residual ``sqrt(r.D^-1 r / b.D^-1 b)`` and the largest Jacobi velocity
   error relative to the largest Jacobi velocity change, ``max |D^-1 r| / max |D^-1 b|``,
   are below ``cg_tolerance`` (:data:`DEFAULT_CG_TOLERANCE`, 1e-2), at most
   ``cg_iterations`` (a safety cap);
5. per node: ``v' = v + dv``, ``x' = x + dt v'``.

Why a step is stable at any stiffness. Implicit Euler dissipates energy when its linear
system is solved; a solve stopped after a fixed number of iterations is not implicit Euler.
SOFA's benchmark beam at 1 MPa needs about 200 Jacobi-preconditioned iterations per 1/60 s
step; a solve cut at 20 and warm-started from the last step's ``dv`` keeps that ``dv`` in
the modes it has not converged, an explicit extrapolation of the velocity: the beam's tip
diverged after about 1 s (1 MPa) and 1.4 s (10 MPa), and a cold start cut at 20 iterations
stayed finite but answered a different, too soft system. The cure is a solve that converges:
the preconditioner is the sparse Cholesky factor of the rest system matrix, turned by the
node rotations (``wcut.preconditioner``, Courtecuisse et al. 2010, 2014; for quadratic elements
the factor of the corners' linear system plus Jacobi), with which the beam needs 1-4
iterations at 0.1-10 MPa (quadratic elements some ten), and the solve starts from zero, so a truncated solve (the
cap) under-solves instead of extrapolating. The tangent is positive semi-definite: the
rotation stiffness is projected to its tension part (``wcut.kernels.rotation``). A released
body's energy then never grows from one step to the next, for Young's moduli 1 kPa-1 GPa,
Poisson's ratios up to 0.49 and steps of 0.1-33 ms (``tests/test_solver.py``).

The tolerance: on the 10x10x40 beam at 0.1 MPa (a 0.3 m swing) the tip's trajectory differs
from a solve to 1e-6 by at most 2e-4 of the swing at 1e-2 and 3e-5 at 1e-3; at 10 MPa by
1e-5; the time discretisation's own error is some percent. A settled state is the same at any
tolerance below 1.

The loop runs on the device: ``wcut.kernels.cg`` keeps its scalars in device arrays and the
iterations are a ``wp.capture_while`` on a convergence flag, so a step records (CPU) or
captures (CUDA) once and a converged solve launches nothing more. Measured against
``warp.optim.linear.cg`` with the same matrix-free operator and Jacobi preconditioner
(``wcut bench``: 11 ms against 1094 ms for 20 iterations on 20k elements), our fused loop is
far faster on the CPU: the generic solver's time goes to tiled dot-product kernels that
Warp's CPU backend emulates.

:meth:`SolverCorotational.check` turns a blow-up into a :class:`SimulationError` naming the
steps: a NaN or infinite value, or a vertex faster than anything the loads can supply.
"""

from __future__ import annotations

import numbers
from collections import deque

import numpy as np
import warp as wp

from .errors import SimulationError
from .kernels import attachments, bending, cg, implicit_euler, tet_p1, tet_p2, tri_p2
from .model import Control, Model, State
from .preconditioner import STRUGGLING_ITERATIONS, RotatedCholesky
from .split_launch import MAX_THREADS, SplitLaunch, ThreadTeam, available_cores

#: the conjugate gradient's preconditioners: the rotated rest factor (``wcut.preconditioner``,
#: the default for tetrahedra) and the diagonal (Jacobi, the default for shells: a stretched
#: membrane's out-of-plane stiffness is its tension's, which the rest factor lacks; on a
#: stretched and bent sheet at 1/30 s Jacobi took 15-57 iterations, the factor 100-500)
PRECONDITIONERS = ("cholesky", "jacobi")

#: default relative tolerance of the conjugate gradient, on ``sqrt(r.P^-1 r / b.P^-1 b)``
DEFAULT_CG_TOLERANCE = 1.0e-2
#: default cap on the conjugate-gradient iterations of a step: a safety net, not a setting
DEFAULT_CG_ITERATIONS = 500

#: :meth:`SolverCorotational.check` calls a run diverged when a vertex moves this many times
#: faster than anything the loads can supply (:attr:`SolverCorotational.speed_limit`)
DIVERGENCE_FACTOR = 10.0

#: captured steps kept per solver (two for the usual ping-pong of states)
GRAPH_CACHE_SIZE = 4

#: elements per CPU thread (by element order) below which another thread costs more than it
#: saves, for the once-per-step element kernel and for the product of every CG iteration: on
#: the 2-core development machine, handing a launch to a thread and hearing back costs about
#: 0.1 ms, the element kernel about 390 ns (P1) or 2500 ns (P2) per element, the product
#: 20-40 ns or 130-290 ns
FORCES_ELEMENTS_PER_THREAD = {1: 1000, 2: 200}
PRODUCT_ELEMENTS_PER_THREAD = {1: 20000, 2: 2000}

#: consecutive nodes per thread of the conjugate gradient's node kernels on a CPU device (one on
#: CUDA; see ``wcut.kernels.cg``): on the 16k nodes of the 10k-element P2 beam, the node kernels
#: of 20 iterations took 5.95 ms with one node per thread and 4.00 ms with 64 (16: 4.22,
#: 256: 4.00), medians of 60 runs side by side
NODES_PER_CPU_THREAD = 64


def _keep(cache: dict, key: tuple, value, held: tuple) -> tuple:
    """Store ``(value, held)`` under ``key``, dropping the oldest entry beyond
    :data:`GRAPH_CACHE_SIZE`; ``held`` are the arrays whose ids the key holds, kept alive so
    that a later array cannot take one's id. Returns the entry."""
    if len(cache) >= GRAPH_CACHE_SIZE:
        cache.pop(next(iter(cache)))
    cache[key] = (value, held)
    return cache[key]


def _thread_count(cpu_threads, model: Model) -> int:
    """The validated ``cpu_threads`` of :class:`SolverCorotational` (1 on CUDA)."""
    if cpu_threads is not None and (isinstance(cpu_threads, bool) or not isinstance(cpu_threads, (int, np.integer))
                                    or not 1 <= cpu_threads <= MAX_THREADS):
        raise SimulationError(f"cpu_threads must be None or an integer in 1..{MAX_THREADS}, got {cpu_threads!r}")
    if not model.device.is_cpu or model.tet_count == 0 or wp.config.mode == "debug":
        return 1  # (debug mode: see wcut.split_launch)
    if cpu_threads is None:
        wanted = model.tet_count // FORCES_ELEMENTS_PER_THREAD[model.tet_order]
        return max(1, min(wanted, available_cores(), MAX_THREADS))
    return min(int(cpu_threads), model.tet_count)


class SolverCorotational:
    """Implicit Euler with one Newton step on corotational tetrahedra, linear or quadratic
    (the kernels of ``wcut.kernels.tet_p1`` or ``tet_p2``, chosen by ``model.tet_order``), and on
    thin shells (the membrane of ``wcut.kernels.tri_p2`` and the hinges of ``bending``).

    Args:
        model: the object to simulate.
        cg_iterations: the cap on conjugate-gradient iterations per step, a safety net (fixed
            for the solver); a converged step costs only the iterations it ran.
        cg_tolerance: the conjugate gradient stops when the Jacobi-scaled residual falls below
            this fraction of the right-hand side's, ``r.D^-1 r <= tol^2 b.D^-1 b`` (D the
            diagonal of A), and every node's Jacobi velocity error below this fraction of the
            largest Jacobi velocity change, ``max |D^-1 r| <= tol max |D^-1 b|`` (so a small
            free piece converges too); 0 runs ``cg_iterations`` or until the residual
            vanishes. See the module's docstring for why 1e-2 is as accurate as a converged
            solve.
        preconditioner: ``"cholesky"``, the rotated factor of the rest system matrix (of its
            projection on the corners, plus Jacobi, for quadratic elements;
            ``wcut.preconditioner``; the default for tetrahedra), or ``"jacobi"`` (the default
            for shells, see :data:`PRECONDITIONERS`). A topological change carries the factor
            over (:meth:`rebuilt`).
        rotation_iterations: maximum polar-decomposition (Newton) iterations per element and
            step, warm-started from the last step; converged elements stop early. Two suffice
            while an object moves smoothly (on a swinging beam, 0.4 m of tip travel over 150
            steps, the tip differs by 3e-8 m from a run iterated to 1e-7 rad; one iteration
            gives 1e-5 m); the margin covers a state moved far from its last rotations, e.g. an
            object placed rotated by half a turn.
        rotation_tolerance: angle (rad) below which the polar iteration stops.
        rotation_stiffness: add to the system matrix the stiffness of the rotation's variation
            (``wcut.kernels.rotation.rotation_stiffness``), projected to its tension part, so
            the Newton step uses the tangent of the corotational force instead of ``R K R^T``
            alone. Without it the transverse stiffness of stretched elements is explicit: a
            band stretched by 30% goes unstable above a step of a few ms. The force is the same
            either way; False gives the thesis's (and SOFA's) ``R K R^T`` system.
        graph_capture: replay repeated steps from a captured graph (see :meth:`step`); the
            results are the same bit for bit. False launches every kernel from Python.
        cpu_threads: threads that share the element kernels on a CPU device, each over its
            own range of elements (:mod:`wcut.split_launch`). None picks one per
            :data:`FORCES_ELEMENTS_PER_THREAD` elements, at most the cores this process may use
            and :data:`wcut.split_launch.MAX_THREADS`, for the once-per-step element kernel; a
            number sets it. The product of every CG iteration is split over them too once the
            model has twice :data:`PRODUCT_ELEMENTS_PER_THREAD` elements. With
            ``graph_capture``, what is not split is still captured (a graph replays its launches
            one after another; inside a capture of the user's, the ranges are recorded one after
            another and the results stay right). Ignored on CUDA and in Warp's debug mode.

    ``step`` allocates nothing once the preconditioner is factored (its first step, a new
    ``dt`` or damping, and a refresh after a topological change factor it and upload the
    factor): every array it touches is created here. The conjugate-gradient launches are
    recorded for the current ``dt``, ``model.rayleigh_stiffness``, ``cg_tolerance`` and factor,
    and recorded again when one of them changes.
    """

    def __init__(self, model: Model, *, cg_iterations: int = DEFAULT_CG_ITERATIONS,
                 cg_tolerance: float = DEFAULT_CG_TOLERANCE, preconditioner: str | None = None,
                 rotation_iterations: int = 8, rotation_tolerance: float = 1.0e-6, rotation_stiffness: bool = True,
                 graph_capture: bool = True, cpu_threads: int | None = None,
                 _carried: RotatedCholesky | None = None):
        for name, value in (("cg_iterations", cg_iterations), ("rotation_iterations", rotation_iterations)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 100000:
                raise SimulationError(f"{name} must be an integer in 1..100000, got {value!r}")
        for name, value in (("cg_tolerance", cg_tolerance), ("rotation_tolerance", rotation_tolerance)):
            if not (isinstance(value, (int, float, np.floating)) and np.isfinite(value) and value >= 0.0):
                raise SimulationError(f"{name} must be a finite number >= 0, got {value!r}")
        if preconditioner is not None and preconditioner not in PRECONDITIONERS:
            raise SimulationError(f"preconditioner must be one of {', '.join(PRECONDITIONERS)}, got {preconditioner!r}")
        self.model = model
        self._settings = dict(cg_iterations=cg_iterations, cg_tolerance=cg_tolerance, preconditioner=preconditioner,
                              rotation_iterations=rotation_iterations, rotation_tolerance=rotation_tolerance,
                              rotation_stiffness=rotation_stiffness, graph_capture=graph_capture,
                              cpu_threads=cpu_threads)
        self._cg_iterations = int(cg_iterations)
        self.cg_tolerance = float(cg_tolerance)
        self.rotation_iterations = int(rotation_iterations)
        self.rotation_tolerance = float(rotation_tolerance)
        self.rotation_stiffness = bool(rotation_stiffness)

        n, d = model.particle_count, model.device
        vec = lambda: wp.zeros(n, dtype=wp.vec3, device=d)  # noqa: E731
        self._force = vec()  # internal and attachment forces of the step
        self.particle_diagonal = vec()
        self.rhs = vec()
        self.inv_diagonal = vec()
        self.mass_scale = wp.zeros(n, dtype=float, device=d)
        self.dv = vec()
        self._r, self._z, self._p, self._q = vec(), vec(), vec(), vec()
        self._elements = tet_p2 if model.tet_order == 2 else tet_p1  # the kernels of the element family
        self.cpu_threads = _thread_count(cpu_threads, model)
        #: whether the product of every CG iteration is split over ``cpu_threads`` too
        self.split_product = (self.cpu_threads > 1
                              and model.tet_count >= 2 * PRODUCT_ELEMENTS_PER_THREAD[model.tet_order])
        self._team = ThreadTeam(self.cpu_threads)
        # scratch of the split element kernels' scatters into _force, particle_diagonal and _q
        self._partials = [wp.zeros((self.cpu_threads - 1, n), dtype=wp.vec3, device=d) for _ in range(3)]
        self._no_partials = wp.zeros((0, n), dtype=wp.vec3, device=d)  # for cg_apply_mass when the product is whole
        self.tet_rotated_gradients = wp.zeros(model.tet_rotation_shape, dtype=wp.mat33, device=d)
        self.tet_rotation_stiffness = wp.zeros(model.tet_rotation_shape, dtype=wp.mat33, device=d)  # V mu units
        self.tri_rotation = wp.zeros((model.tri_count, 3), dtype=tri_p2.mat32, device=d)
        self.tri_tension = wp.zeros((model.tri_count, 3), dtype=wp.mat22, device=d)  # A h sigma+ (N*m)
        self._rz = wp.zeros(self._cg_iterations + 1, dtype=float, device=d)  # r.P^-1 r per iteration
        self._rd = wp.zeros(self._cg_iterations + 1, dtype=float, device=d)  # r.D^-1 r per iteration
        self._pq = wp.zeros(self._cg_iterations, dtype=float, device=d)
        self._norms = wp.zeros(3, dtype=float, device=d)  # tol^2 b.D^-1 b (the threshold), b.D^-1 b, tol max|D^-1 b|
        self._velocity = wp.zeros(self._cg_iterations + 1, dtype=float, device=d)  # max |D^-1 r| per iteration
        self._counter = wp.zeros(1, dtype=wp.int32, device=d)  # the CG iteration
        self._running = wp.zeros(1, dtype=wp.int32, device=d)  # the CG loop's condition
        self._nonfinite = wp.zeros(1, dtype=wp.int32, device=d)
        # since the last check(): the largest squared speed (m^2/s^2), external load per mass
        # (m/s^2) and attachment gap (m)
        self._speed_sq_max = wp.zeros(1, dtype=float, device=d)
        self._load_acceleration = wp.zeros(1, dtype=float, device=d)
        self._reach_max = wp.zeros(1, dtype=float, device=d)
        #: steps taken and time simulated (s) by this solver and those it was rebuilt from
        self.step_count, self.elapsed, self._last_dt = 0, 0.0, 1.0
        self._checked_steps = 0
        self._start_speed: float | None = None
        self._wave_speed = _wave_speed(model)
        #: the rotated Cholesky factor (``wcut.preconditioner``), or None for Jacobi
        self.preconditioner = None
        if preconditioner is None:
            preconditioner = "cholesky" if model.tet_count else "jacobi"
        if preconditioner == "cholesky":
            self.preconditioner = _carried if _carried is not None else RotatedCholesky(model)
        self._recorded_for: tuple | None = None
        self._concurrent_solve = False  # the factor's solves run on two threads: no graph
        # recorded launches, or SplitLaunch objects: anything with launch()
        self._cg_start: list = []  # before the loop
        self._cg_body: list = []  # one iteration
        self.graph_capture = bool(graph_capture)
        self._graphs: dict = {}  # capture key -> (graph, the objects whose ids the key holds)
        self._element_passes: dict = {}  # the same for split element passes: key -> (SplitLaunch, held)
        self._seen: deque = deque(maxlen=2 * GRAPH_CACHE_SIZE)  # keys stepped lately: their next step captures

    def rebuilt(self, model: Model, change) -> "SolverCorotational":
        """A solver with this one's settings for ``model``, which ``change`` (a
        :class:`wcut.topology.TopologyChange`) made from this solver's model
        (:meth:`wcut.model.Model.rebuild`). The preconditioner's factor is carried over (the
        vertices the change touched get a patch until a new factor, computed in the
        background, is taken; ``wcut.preconditioner``); this solver must not step again."""
        carried = None if self.preconditioner is None else self.preconditioner.carried(model, change)
        solver = SolverCorotational(model, **self._settings, _carried=carried)
        solver.step_count, solver.elapsed, solver._start_speed = self.step_count, self.elapsed, self._start_speed
        solver._checked_steps, solver._last_dt = self._checked_steps, self._last_dt
        return solver

    @property
    def cg_iterations(self) -> int:
        """Maximum conjugate-gradient iterations per step (set at construction)."""
        return self._cg_iterations

    # -- launches -------------------------------------------------------------------------

    def stiffness_scale(self, dt: float) -> float:
        """Factor of the stiffness matrix K in the system matrix A: ``dt^2 + dt beta`` (s^2)."""
        return dt * dt + dt * self.model.rayleigh_stiffness

    def launch_element_pass(self, state_in: State, state_out: State, dt: float, record: bool = False):
        """The once-per-step element kernel (rotations, forces, right-hand side terms,
        preconditioner diagonal, warm-start product) of the tetrahedra, split over
        ``cpu_threads``; with ``record`` it only records it and returns an object whose
        ``launch()`` runs it. Shell triangles and hinges get theirs in :meth:`launch_shell_pass`."""
        m = self.model

        def launch(lo: int, hi: int, targets: list, record_cmd: bool = True):
            return wp.launch(self._elements.tet_forces, hi - lo, device=m.device, record_cmd=record_cmd,
                             inputs=[m.tet_indices[lo:hi], m.tet_poses[lo:hi], m.tet_stiffness[lo:hi],
                                     *([m.particle_q] if m.tet_order == 1 else []),
                                     state_in.particle_q, state_in.particle_qd, state_in.tet_rotation[lo:hi],
                                     dt + m.rayleigh_stiffness, self.stiffness_scale(dt), self.rotation_iterations,
                                     self.rotation_tolerance, int(self.rotation_stiffness)],
                             outputs=[state_out.tet_rotation[lo:hi], self.tet_rotated_gradients[lo:hi],
                                      self.tet_rotation_stiffness[lo:hi], *targets])

        targets = [self._force, self.particle_diagonal]
        if self.cpu_threads == 1:
            return launch(0, m.tet_count, targets, record)
        # recording the ranges costs about 0.5 ms: kept per states and settings, as graphs are
        held = (state_in.particle_q, state_in.particle_qd, state_in.tet_rotation, state_out.tet_rotation)
        key = (tuple(id(a) for a in held), dt, m.rayleigh_stiffness, self.rotation_iterations,
               self.rotation_tolerance, self.rotation_stiffness)
        split = self._element_passes.get(key, (None,))[0]
        if split is None:
            split = SplitLaunch(self._team, m.tet_count, launch, targets, self._partials[:2])
            _keep(self._element_passes, key, split, held)
        if not record:
            split.launch()
        return split

    def launch_shell_pass(self, state_in: State, dt: float) -> None:
        """The once-per-step kernels of the shell triangles and bending hinges (the terms of
        :meth:`launch_element_pass`)."""
        m = self.model
        velocity_scale, matrix_scale = dt + m.rayleigh_stiffness, self.stiffness_scale(dt)
        outputs = [self._force, self.particle_diagonal]
        wp.launch(tri_p2.tri_forces, m.tri_count, device=m.device,
                  inputs=[m.tri_indices, m.tri_poses, m.tri_stiffness, state_in.particle_q, state_in.particle_qd,
                          velocity_scale, matrix_scale],
                  outputs=[self.tri_rotation, self.tri_tension, *outputs])
        if m.edge_count:
            wp.launch(bending.hinge_forces, m.edge_count, device=m.device,
                      inputs=[m.edge_indices, m.edge_weights, m.edge_stiffness, m.edge_rest_curvature,
                              state_in.particle_q, state_in.particle_qd, velocity_scale, matrix_scale],
                      outputs=outputs)

    def _record_cg(self, dt: float) -> None:
        """Record the conjugate-gradient launches for the current dt, damping, tolerance and
        preconditioner factor: those before the loop and those of one iteration."""
        m, n, d = self.model, self.model.particle_count, self.model.device
        r, z, p, q, rz, pq, norms, counter = (self._r, self._z, self._p, self._q, self._rz, self._pq, self._norms,
                                              self._counter)
        stiffness_scale = self.stiffness_scale(dt)
        product_partials = self._partials[2] if self.split_product else self._no_partials
        chunk = NODES_PER_CPU_THREAD if d.is_cpu else 1
        node_threads = (n + chunk - 1) // chunk
        jacobi = int(self.preconditioner is None)

        # with Jacobi, rz is rd (r.z = r.D^-1 r); a factor writes rz at the start of an iteration
        rd = rz if jacobi else self._rd
        start = [wp.launch(cg.cg_init, node_threads, device=d, record_cmd=True,
                           inputs=[chunk, jacobi, self.rhs, self.inv_diagonal],
                           outputs=[self.dv, r, z, p, q, rd, self._velocity]),
                 wp.launch(cg.cg_start, 1, device=d, record_cmd=True,
                           inputs=[self.cg_tolerance ** 2, self._cg_iterations, rd, self._velocity],
                           outputs=[norms, self._running])]
        team = self._team if self.cpu_threads > 1 else None
        self._concurrent_solve = not jacobi and self.preconditioner.concurrent(team)
        body = [] if jacobi else self.preconditioner.record_apply(chunk, counter, self.inv_diagonal, r, z, rz, team,
                                                                   product=self._local_product(dt))
        body.append(wp.launch(cg.cg_direction, node_threads, device=d, record_cmd=True,
                              inputs=[chunk, counter, z, rz], outputs=[p]))
        if m.tet_count:
            body.append(self._record_tet_matvec(stiffness_scale))
        if m.tri_count:
            body.append(wp.launch(tri_p2.tri_matvec, m.tri_count, device=d, record_cmd=True,
                                  inputs=[m.tri_indices, m.tri_poses, m.tri_stiffness, self.tri_rotation,
                                          self.tri_tension, p, stiffness_scale], outputs=[q]))
        if m.edge_count:
            # a hinge's matrix k w w^T is an attachment spring's (see wcut.kernels.bending)
            body.append(wp.launch(attachments.attachment_matvec, m.edge_count, device=d, record_cmd=True,
                                  inputs=[m.edge_indices, m.edge_weights, m.edge_stiffness, p, stiffness_scale],
                                  outputs=[q]))
        if m.attachment_count:
            body.append(self._record_attachment_matvec(p, q, dt))
        body.append(wp.launch(cg.cg_apply_mass, node_threads, device=d, record_cmd=True,
                              inputs=[chunk, counter, self.inv_diagonal, self.mass_scale, p],
                              outputs=[product_partials, q, pq]))
        body.append(wp.launch(cg.cg_update, node_threads, device=d, record_cmd=True,
                              inputs=[chunk, jacobi, counter, self.inv_diagonal, p, pq, rz],
                              outputs=[self.dv, r, z, q, rd, self._velocity]))
        body.append(wp.launch(cg.cg_advance, 1, device=d, record_cmd=True,
                              inputs=[self._cg_iterations, rd, self._velocity, norms],
                              outputs=[counter, self._running]))
        self._cg_start, self._cg_body = start, body
        self._recorded_for = self._record_key(dt)

    def _record_key(self, dt: float) -> tuple:
        """What the recorded conjugate-gradient launches depend on besides their arrays."""
        generation = None if self.preconditioner is None else self.preconditioner.generation
        return dt, self.model.rayleigh_stiffness, self.cg_tolerance, generation

    def _local_product(self, dt: float):
        """``product(elements, nodes, x, y)``: the recorded launches of ``y += A x`` (the system
        matrix of a step of ``dt``) from the listed elements, every attachment and the mass of
        the listed nodes: the patch's products (``wcut.preconditioner``)."""
        m, d, stiffness_scale = self.model, self.model.device, self.stiffness_scale(dt)

        def product(elements, nodes, x, y) -> list:
            launches = [wp.launch(
                self._elements.tet_matvec_listed, elements.shape[0], device=d, record_cmd=True,
                inputs=[elements, m.tet_indices, self.tet_rotated_gradients, self.tet_rotation_stiffness,
                        m.tet_stiffness, x, stiffness_scale], outputs=[y])]
            if m.attachment_count:
                launches.append(self._record_attachment_matvec(x, y, dt))
            launches.append(wp.launch(cg.listed_apply_mass, nodes.shape[0], device=d, record_cmd=True,
                                      inputs=[nodes, self.inv_diagonal, self.mass_scale, x], outputs=[y]))
            return launches

        return product

    def _record_attachment_matvec(self, x, y, dt: float):
        """The recorded attachment springs' product ``y += dt^2 K_attach x``."""
        m = self.model
        return wp.launch(attachments.attachment_matvec, m.attachment_count, device=m.device, record_cmd=True,
                         inputs=[m.attachment_indices, m.attachment_weights, m.attachment_stiffness, x, dt * dt],
                         outputs=[y])

    def _record_tet_matvec(self, stiffness_scale: float):
        """The recorded element product ``q += c_A K_t p`` of one CG iteration, split over
        ``cpu_threads``."""
        m = self.model

        def record(lo: int, hi: int, targets: list):
            return wp.launch(self._elements.tet_matvec, hi - lo, device=m.device, record_cmd=True,
                             inputs=[m.tet_indices[lo:hi], self.tet_rotated_gradients[lo:hi],
                                     self.tet_rotation_stiffness[lo:hi], m.tet_stiffness[lo:hi], self._p,
                                     stiffness_scale],
                             outputs=targets)

        if not self.split_product:
            return record(0, m.tet_count, [self._q])
        return SplitLaunch(self._team, m.tet_count, record, [self._q], self._partials[2:],
                           add_partials=False)  # cg_apply_mass adds them

    def _check(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Cheap checks that keep a wrong argument from reading out of bounds (no allocation)."""
        if not (isinstance(dt, (int, float)) and 0.0 < dt < float("inf")):
            raise SimulationError(f"time step must be a positive finite number of seconds, got {dt!r}")
        m = self.model
        for name, state in (("state_in", state_in), ("state_out", state_out)):
            for array, count in ((state.particle_q, m.particle_count), (state.particle_qd, m.particle_count),
                                 (state.particle_f, m.particle_count), (state.tet_rotation, m.tet_count)):
                if array.shape[0] != count or array.device != m.device:
                    raise SimulationError(f"{name} does not belong to this model (a state made by another "
                                          f"model's state()?)")
        if m.attachment_count:
            if control is None:
                raise SimulationError("the model has attachments: step needs a Control with their targets")
            target = control.attachment_target
            if target.shape[0] != m.attachment_count or target.device != m.device:
                raise SimulationError("control does not belong to this model (made by another model's control()?)")

    def step(self, state_in: State, state_out: State, control: Control | None, contacts=None,
             dt: float | None = None) -> None:
        """Advance by ``dt`` seconds from ``state_in`` to ``state_out`` (they may be the same).

        Called as ``step(state_in, state_out, control, dt)`` or, as Newton's solvers are,
        ``step(state_in, state_out, control, contacts, dt)`` with ``contacts`` None (wcut
        handles no contacts). ``dt`` may be any real number type (a NumPy scalar too).
        ``control`` may be None when the model has no attachments. External forces are read
        from ``state_in.particle_f``.

        With ``graph_capture``, the second step with the same states, control and settings
        captures the step's launches into a graph and later steps replay it
        (``wp.capture_launch``): on the CPU, Warp replays it in a native loop, without the
        Python cost of some 300 launches per step (10 us each), which dominates small
        models. The graph holds the arrays the states and control had at capture: write
        into them (``assign``, ``numpy()`` views), do not replace them. An element kernel
        split over threads runs outside the graph (before it, for the element pass); with
        the product split too, nothing is captured.
        """
        if dt is None:  # step(state_in, state_out, control, dt)
            contacts, dt = None, contacts
        if contacts is not None:
            raise SimulationError("step: wcut handles no contacts; pass contacts=None")
        dt = _seconds(dt)
        self._check(state_in, state_out, control, dt)
        m = self.model
        if self._start_speed is None:  # what the divergence check allows for initial velocities
            self._start_speed = float(np.sqrt((state_in.particle_qd.numpy().astype(np.float64) ** 2).sum(axis=1).max(
                initial=0.0)))
        self.step_count += 1
        self.elapsed += dt
        self._last_dt = dt
        if self.preconditioner is not None:
            generation = self.preconditioner.generation
            # (a solver made by rebuilt() has run no iterations yet: its count is 0)
            struggling = self.preconditioner.refreshing and self.last_cg_iterations > STRUGGLING_ITERATIONS
            self.preconditioner.update(dt, struggling)
            if self.preconditioner.generation != generation:
                self._graphs.clear()  # they hold the launches of the factor before
        if self._recorded_for != self._record_key(dt):
            self._record_cg(dt)
        if not self.graph_capture or self.split_product or self._concurrent_solve or m.device.is_capturing:
            self._launch_step(state_in, state_out, control, dt)  # (inside the user's capture: into it)
            return
        captured = self._launch_step
        if self.cpu_threads > 1:  # the split element pass from here, the rest in the graph
            self._launch_element_part(state_in, state_out, dt)
            captured = self._launch_solve_part
        key, held = self._capture_key(state_in, state_out, control, dt)
        graph = self._graphs.get(key)
        if graph is None and key in self._seen:
            with wp.ScopedCapture(device=m.device) as capture:
                captured(state_in, state_out, control, dt)
            graph = _keep(self._graphs, key, capture.graph, held)
        if graph is None:
            self._seen.append(key)
            captured(state_in, state_out, control, dt)
        else:
            wp.capture_launch(graph[0])

    def _capture_key(self, state_in: State, state_out: State, control: Control | None, dt: float) -> tuple:
        """``(key, held)``: what a captured step depends on, its arrays by identity and every
        value passed by value, and the arrays themselves (a cached graph keeps them alive, so
        that a later array cannot take one's id)."""
        m = self.model
        held = (state_in.particle_q, state_in.particle_qd, state_in.particle_f, state_in.tet_rotation,
                state_out.particle_q, state_out.particle_qd, state_out.tet_rotation,
                None if control is None else control.attachment_target)
        key = (tuple(id(a) for a in held), dt, m.rayleigh_stiffness, m.rayleigh_mass, tuple(m.gravity),
               self.cg_tolerance, self.rotation_iterations, self.rotation_tolerance, self.rotation_stiffness,
               self._recorded_for)
        return key, held

    def _launch_step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """The launches of one step (see the module's docstring)."""
        self._launch_element_part(state_in, state_out, dt)
        self._launch_solve_part(state_in, state_out, control, dt)

    def _launch_element_part(self, state_in: State, state_out: State, dt: float) -> None:
        """Step 1 of a step: the element pass of the tetrahedra, into cleared sums."""
        self._force.zero_()
        self.particle_diagonal.zero_()
        for partial in self._partials:  # zero unless a split launch was interrupted
            partial.zero_()
        if self.model.tet_count:
            self.launch_element_pass(state_in, state_out, dt)

    def _launch_solve_part(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Steps 1 (shells) to 5 of a step, after :meth:`_launch_element_part`."""
        m, d = self.model, self.model.device
        if m.tri_count:
            self.launch_shell_pass(state_in, dt)
        if self.preconditioner is not None:
            self.preconditioner.launch_node_rotations(state_out)
        if m.attachment_count:
            wp.launch(attachments.attachment_forces, m.attachment_count, device=d,
                      inputs=[m.attachment_indices, m.attachment_weights, m.attachment_stiffness,
                              control.attachment_target, state_in.particle_q, state_in.particle_qd, dt, dt * dt],
                      outputs=[self._force, self.particle_diagonal, self._reach_max])
        wp.launch(implicit_euler.assemble_system, m.particle_count, device=d,
                  inputs=[m.particle_mass, m.particle_load_mass, m.particle_fixed, state_in.particle_qd, self._force,
                          state_in.particle_f,
                          self.particle_diagonal, m.gravity, dt, m.rayleigh_mass],
                  outputs=[self.rhs, self.inv_diagonal, self.mass_scale, self._load_acceleration])
        self.launch_cg()
        wp.launch(implicit_euler.integrate, m.particle_count, device=d,
                  inputs=[m.particle_fixed, state_in.particle_q, state_in.particle_qd, self.dv, dt],
                  outputs=[state_out.particle_q, state_out.particle_qd, self._nonfinite, self._speed_sq_max])

    def launch_cg(self) -> None:
        """The conjugate gradient on the system of the last :meth:`step` (or the last element
        pass and ``assemble_system``): its start, then iterations while it has not converged."""
        self._rz.zero_()
        self._rd.zero_()
        self._velocity.zero_()
        self._pq.zero_()
        self._counter.zero_()
        for cmd in self._cg_start:
            cmd.launch()
        wp.capture_while(self._running, self._launch_cg_iteration)

    def _launch_cg_iteration(self) -> None:
        for cmd in self._cg_body:
            cmd.launch()

    # -- diagnostics (these read back from the device) ----------------------------------

    @property
    def last_cg_iterations(self) -> int:
        """Conjugate-gradient iterations the last step ran."""
        return int(self._counter.numpy()[0])

    @property
    def last_relative_residual(self) -> float:
        """Relative Jacobi-scaled residual ``sqrt(r.D^-1 r / b.D^-1 b)`` after the last step."""
        rd = (self._rz if self.preconditioner is None else self._rd).numpy()
        b_norm = float(self._norms.numpy()[1])
        if b_norm <= 0.0:
            return 0.0
        return float(np.sqrt(max(float(rd[self.last_cg_iterations]), 0.0) / b_norm))

    @property
    def speed_limit(self) -> float:
        """The speed (m/s) beyond which :meth:`check` calls the run diverged: far beyond what the
        loads can supply, :data:`DIVERGENCE_FACTOR` times the elastic (P-)wave speed of the
        stiffest material plus the initial speed, what gravity and the external forces
        accelerate to in the time simulated, and an attachment's gap crossed in one step."""
        load = float(np.linalg.norm(np.asarray(self.model.gravity))) + float(self._load_acceleration.numpy()[0])
        reach = float(self._reach_max.numpy()[0]) / self._last_dt if self.step_count else 0.0
        return DIVERGENCE_FACTOR * (self._wave_speed + (self._start_speed or 0.0) + load * self.elapsed + reach)

    def check(self) -> None:
        """Raise :class:`SimulationError` if a step since the last check produced a NaN or
        infinite value, or moved a vertex faster than :attr:`speed_limit`: a blow-up is an
        error, not an animation. Reads back from the device: call it once per frame, not per
        step."""
        first, last = self._checked_steps + 1, self.step_count
        count = int(self._nonfinite.numpy()[0])
        speed = float(np.sqrt(max(float(self._speed_sq_max.numpy()[0]), 0.0)))
        limit = self.speed_limit
        self._checked_steps = self.step_count
        self._speed_sq_max.zero_()
        self._reach_max.zero_()
        when = f"step {last}" if first >= last else f"steps {first}-{last}"
        if count:
            raise SimulationError(f"the simulation diverged in {when} (t = {self.elapsed:.4g} s): {count} non-finite "
                                  f"vertex updates")
        if speed > limit:
            raise SimulationError(f"the simulation diverged in {when} (t = {self.elapsed:.4g} s): a vertex moved at "
                                  f"{speed:.3g} m/s, beyond the {limit:.3g} m/s the loads and the material's wave "
                                  f"speed allow")


def _seconds(dt) -> float:
    """A time step (s) as a float: any real number (a NumPy scalar, a 0-d array), not a bool."""
    if isinstance(dt, (bool, np.bool_)) or not isinstance(dt, (numbers.Real, np.ndarray)) \
            or (isinstance(dt, np.ndarray) and (dt.shape != () or dt.dtype.kind not in "iuf")):
        raise SimulationError(f"time step must be a positive finite number of seconds, got {dt!r}")
    return float(dt)


def _wave_speed(model: Model) -> float:
    """The largest elastic P-wave speed ``sqrt((lambda + 2 mu) / rho)`` (m/s) of the model's
    elements (tetrahedra or shell triangles)."""
    if model.tet_count:
        E, nu, rho = model.tet_youngs_modulus, model.tet_poisson_ratio, model.tet_density
    elif model.tri_count:
        E, nu, rho = model.tri_youngs_modulus, model.tri_poisson_ratio, model.tri_density
    else:
        return 0.0
    E, nu, rho = (a.numpy().astype(np.float64) for a in (E, nu, rho))
    modulus = E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return float(np.sqrt((modulus / rho).max()))
