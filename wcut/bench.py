"""Benchmarks behind ``wcut bench``: kernel costs and a full step on SOFA's benchmark beams,
side by side with a scipy reference of the same step (``wcut.reference``).

Each scene is a beam of ``nx * ny * nz`` hexahedra split into five tetrahedra each, clamped at
one end, under gravity, with 20 conjugate-gradient iterations per step (tolerance 0, so every
iteration runs). Times are medians of repeated runs measured in this one process, so ratios
compare like with like on a shared, noisy machine.
"""

from __future__ import annotations

import functools
import gc
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from .errors import WcutError
from .io import atomic_path, check_writable
from .mesh import beam, edge_matrices, tet_volumes
from .model import Model
from .solver import SolverCorotational
from .split_launch import available_cores

#: name, hexahedra along x, y, z, and beam size (m): SOFA's TetrahedronFEMForceField beams
SCENES = (("beam_10x10x40", (10, 10, 40), (0.1, 0.1, 0.4)), ("beam_16x16x76", (16, 16, 76), (0.16, 0.16, 0.76)))
CG_ITERATIONS = 20
DT = 0.01

#: Cut-event meshes: name, hexahedra along x, y, z, size (m). Thin beams of 1 cm cells whose
#: 4 x 5 cross-section a plane x = const crosses in 100 elements, whatever the length.
CUT_SCENES = (("cut_20k", (200, 4, 5), (2.0, 0.04, 0.05)), ("cut_100k", (1000, 4, 5), (10.0, 0.04, 0.05)))
#: Quadratic-element beams: name, hexahedra along x, y, z, size (m); 5 tetrahedra per cell.
P2_SCENES = (("p2_beam_10k", (10, 10, 20), (0.1, 0.1, 0.2)),)
#: the augmented-reality loop: a synthetic capture of this scene (thesis 7.7.1, 600 elements)
AR_SCENE = Path(__file__).resolve().parents[1] / "scenes" / "ar" / "band_cut_side.toml"
#: a blade in a simulation: the organ opened by a scalpel, 4300 elements, one step per frame
BLADE_SCENE = Path(__file__).resolve().parents[1] / "scenes" / "organ_cut.toml"


def bench_detection(feature_count: int = 500, pair_count: int = 6800, repeats: int = 200) -> dict:
    """Cut detection at the thesis's scale (the V-example: 531 features, 6795 pairs): the time
    of one :meth:`wcut.ar.detection.CutDetector.update` on a frame without a cut (ms)."""
    from .ar.detection import CutDetector, DetectionParams

    rng = np.random.default_rng(0)
    side = 0.1
    p0 = np.column_stack([rng.uniform(0, side, (feature_count, 2)), np.zeros(feature_count)])
    # a radius giving about pair_count pairs: n^2/2 * (pi r^2 / side^2) = pairs, less the border
    radius = side * np.sqrt(2.0 * pair_count / (np.pi * feature_count ** 2)) * 1.1
    detector = CutDetector(p0, DetectionParams(radius=radius, cut_point_radius=radius, tau=10.0, min_measure=1e-3))
    current = p0 * [1.3, 1.0, 1.0]
    target = current + rng.normal(0.0, 1e-4, p0.shape)
    active = np.ones(feature_count, bool)
    ms = 1e3 * _median_seconds(lambda: detector.update(current, target, active), repeats, warmup=5)
    return {"features": feature_count, "pairs": len(detector.pairs), "update_ms": round(ms, 4)}


def bench_ar_loop(frames: int, scene=AR_SCENE) -> dict:
    """The whole augmented-reality loop (tracking, lifting, solve, detection, cuts) on a
    synthetic capture of ``scene`` (``frames`` frames after the first): frames per second."""
    import tempfile

    from .ar.pipeline import run_ar
    from .ar.synth import synthesize

    with tempfile.TemporaryDirectory(prefix="wcut-bench-ar-") as tmp:
        synthesize(scene, Path(tmp) / "capture", frames=frames, progress=False)
        result = run_ar(Path(tmp) / "capture", Path(tmp) / "out.usdc", progress=False)
    m = result.metrics()
    return {"scene": Path(scene).stem, "frames": m["frames"], "elements": result.elements_final,
            "features": m["features"], "pairs": m["pairs_initial"], "fps_mean": round(m["fps_mean"], 1),
            "frame_ms_mean": round(m["frame_ms_mean"], 2), "detection_ms_mean": round(m["detection_ms_mean"], 4),
            "cuts_detected": m["cuts_detected"], "dice_final": round(m["dice_final"], 4)}


def bench_blade_scene(frames: int | None = None, scene=BLADE_SCENE) -> dict:
    """``frames`` frames of ``scene`` (default: all of them; steps and the blade's cut events, as ``wcut run`` runs
    them, without writing USD): the mean step, the wall time of the blade's cuts (every frame
    of its path, those that changed nothing too), the cut events that changed the mesh, the
    conjugate-gradient iterations of the last step of each frame, summed, and the real-time
    factor (simulated time over the wall time of the steps and cuts)."""
    from .scene import Simulation, load_scene

    loaded = load_scene(scene)
    sim = Simulation(loaded)
    frames = loaded.frame_count if frames is None else frames
    iterations = 0
    for _ in range(frames):
        solver = sim.solver  # (a cut event replaces it after the frame's steps)
        sim.advance()
        iterations += solver.last_cg_iterations
    steps = frames * sim.substeps
    return {"scene": Path(scene).stem, "frames": frames, "elements": sim.model.tet_count, "cut_events": sim.cut_events,
            "step_ms_mean": round(1e3 * sim.step_seconds / steps, 2),
            "cut_seconds": round(sim.cut_seconds, 3),
            "cg_iterations": iterations,
            "real_time_factor": round(frames / loaded.simulation["fps"] / (sim.step_seconds + sim.cut_seconds), 3)}


#: Time to accuracy: SOFA's beams (clamped at z = 0, transverse gravity, 1000 kg/m^3, Poisson
#: 0.3) at these Young's moduli (Pa), one step per 1/60 s frame, Rayleigh mass damping 1/s so
#: that the softest beam settles within seconds; settled when the tip has stayed within 1% of its
#: static deflection for 30 steps once the load is whole, or after 30 s simulated
ACCURACY_MODULI = (1.0e5, 1.0e6, 1.0e7)
ACCURACY_DT = 1.0 / 60.0
ACCURACY_DAMPING = 1.0
ACCURACY_MAX_TIME = 30.0
#: Each case runs twice: gravity applied at once (the beam released from rest), and raised
#: smoothly over 3 s (:func:`load_ramp`), as the static solve's increments raise it, over more
#: than the slowest beam's first period (2.2 s at 0.1 MPa, 16x16x76). A load applied at once
#: swings a beam to up to twice its static deflection: the 16x16x76 beam at 0.1 MPa, whose
#: static state already squeezes elements at the clamp to 8.9% of their volume, then crushes
#: them through and comes to rest with 32 inside out, 9.3% from the static tip (at dt = 1/600 s
#: too: the motion, not the step); raised over 3 s, it settles on the static state.
ACCURACY_RAMPS = (0.0, 3.0)
#: relative residual of the static reference solve (see static_tip_deflection)
STATIC_TOLERANCE = 1e-5
SETTLED_STEPS = 30
#: steps of the Jacobi-preconditioned CG run beside each (to the same tolerance)
JACOBI_STEPS = 20


#: Where the plane crosses its cell, as a fraction of the cell (not through a node layer).
CUT_OFFSET = 0.37


def _median_seconds(fn, repeats: int, warmup: int = 1) -> float:
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


#: SOFA's benchmark solver: 20 Jacobi-preconditioned CG iterations, every one run
FIXED_ITERATIONS = dict(cg_iterations=CG_ITERATIONS, cg_tolerance=0.0, preconditioner="jacobi")


def _bent_solvers(model, control=None, thread_counts=(None, 1), settings=FIXED_ITERATIONS):
    """One solver per entry of ``thread_counts`` (``cpu_threads``; None: the default), each
    with its own state stepped 10 times, so rotations are not the identity; a dict keyed by
    the entry, of ``(solver, state, scratch)``. ``settings``: the solver's other arguments."""
    runs = {}
    for threads in dict.fromkeys(thread_counts):
        same = [run for run in runs.values() if run[0].cpu_threads == threads]
        if same:  # the default came to this count: one solver serves both
            runs[threads] = same[0]
            continue
        solver = SolverCorotational(model, **settings, cpu_threads=threads)
        state, scratch = model.state(), model.state()
        for _ in range(10):
            solver.step(state, scratch, control, DT)
            state, scratch = scratch, state
        runs[threads] = (solver, state, scratch)
    return runs


def _alternating_step_seconds(runs, control, repeats: int, iterations: list | None = None) -> dict:
    """Median step time of each run of :func:`_bent_solvers`, timed in turn, step after step,
    so that a shared machine's load changes touch them alike (the CG iterations of every timed
    step appended to ``iterations``)."""
    distinct = {id(run): run for run in runs.values()}
    samples = {key: [] for key in distinct}
    for k in range(repeats + 1):  # the first round warms up
        for key, (solver, state, scratch) in distinct.items():
            start = time.perf_counter()
            solver.step(state, scratch, control, DT)
            wp.synchronize_device(solver.model.device)
            if k:
                samples[key].append(time.perf_counter() - start)
                if iterations is not None:
                    iterations.append(solver.last_cg_iterations)
    return {key: statistics.median(samples[id(run)]) for key, run in runs.items()}


def _clamped(mesh):
    """The vertices of a benchmark beam's clamped end, z = 0."""
    return mesh.vertices_in_box((-1.0, -1.0, -1.0), (1.0, 1.0, 1e-9))


def _scene_model(cells, size, device=None):
    mesh = beam(*cells, size=size)
    fixed = _clamped(mesh)
    model = Model(mesh, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3, rayleigh_mass=0.1,
                  rayleigh_stiffness=0.01, gravity=(9.81, 0.0, 0.0), fixed=fixed, device=device)
    return mesh, model, fixed


def static_tip_deflection(mesh, fixed, youngs_modulus: float, tip: int) -> np.ndarray:
    """The tip's static deflection (m) of a benchmark beam under gravity, from the independent
    scipy reference (``ScipyCorotationalStep.static_equilibrium``, which splits the load into
    increments as the deflection needs)."""
    from .reference import ScipyCorotationalStep

    ref = ScipyCorotationalStep(mesh.vertices, mesh.tets, density=1000.0, youngs_modulus=youngs_modulus,
                                poisson_ratio=0.3, gravity=(0.0, -9.81, 0.0), fixed=fixed)
    # a residual of 1e-5 of the load puts the tip far inside the 1% the benchmark asks for; the
    # tangent's projected rotation term makes Newton's method converge only linearly when the
    # beam hangs at large angles (0.1 MPa), where each further decade costs minutes
    return ref.static_equilibrium(tolerance=STATIC_TOLERANCE)[tip] - mesh.vertices[tip]


def load_ramp(t: float, duration: float) -> float:
    """The fraction of the load applied at time ``t`` (s): a smoothstep from 0 to 1 over
    ``duration`` (s), whose rate starts and ends at zero."""
    r = min(1.0, max(0.0, t / duration)) if duration > 0.0 else 1.0
    return r * r * (3.0 - 2.0 * r)


def _mean_ms(seconds: list[float]) -> float:
    """The mean (ms) of step times (s); 0 for none."""
    return 1e3 * float(np.mean(seconds)) if seconds else 0.0


def _settle(model, solver, tip: int, static: np.ndarray, load: np.ndarray, max_steps: int, ramp: float,
            early_steps: int = JACOBI_STEPS) -> dict:
    """Step from rest under the nodal forces ``load`` (N, 3) raised by :func:`load_ramp` over
    ``ramp`` (s) until, once whole, the tip has stayed within 1% of ``static`` for
    :data:`SETTLED_STEPS` steps (or ``max_steps``); wall time of the first step (the one-time
    factorization of the preconditioner, and the recording of the launches) and mean wall time
    and CG iterations of the steps after it, and of those among the first ``early_steps``."""
    state, scratch = model.state(), model.state()
    rest, size = model.particle_q.numpy()[tip].astype(np.float64), float(np.linalg.norm(static))
    seconds, iterations, within = [], [], 0  # per step
    applied = None  # the fraction of the load in both states' particle_f
    while len(seconds) < max_steps and within < SETTLED_STEPS:
        fraction = load_ramp((len(seconds) + 1) * ACCURACY_DT, ramp)  # (implicit Euler: the load at the step's end)
        if fraction != applied:  # (the states take turns as the step's input)
            for each in (state, scratch):
                each.particle_f.assign((fraction * load).astype(np.float32))
            applied = fraction
        start = time.perf_counter()
        solver.step(state, scratch, None, ACCURACY_DT)
        wp.synchronize_device(model.device)
        seconds.append(time.perf_counter() - start)
        iterations.append(solver.last_cg_iterations)
        state, scratch = scratch, state
        if len(seconds) % 10 == 0:
            solver.check()
        error = float(np.linalg.norm(state.particle_q.numpy()[tip] - rest - static))
        within = within + 1 if error <= 0.01 * size and fraction == 1.0 else 0
    return {"steps": len(seconds), "first_step_ms": 1e3 * seconds[0], "step_ms": _mean_ms(seconds[1:]),
            "iterations": float(np.mean(iterations)), "early_step_ms": _mean_ms(seconds[1:early_steps]),
            "early_iterations": float(np.mean(iterations[:early_steps])),
            "settled": within >= SETTLED_STEPS, "tip_error": error / size,
            "inverted": inverted_count(model, state.particle_q.numpy())}


def inverted_count(model, positions: np.ndarray) -> int:
    """Elements (P1, or the corners of P2) turned inside out at ``positions`` (N, 3), m.

    Corotational linear elasticity has equilibria with inverted elements: released from rest,
    the 16x16x76 beam at 0.1 MPa swings past its static deflection, crushes elements at the
    clamp (smallest stretch 0.07) and comes to rest with some inside out, its tip 9.3% from
    the static solve of Newton's method, which stays on the branch without inversion. A case
    that does not settle says so here."""
    tets = model.tet_indices.numpy()[:, :4]
    rest = tet_volumes(model.particle_q.numpy().astype(np.float64), tets)
    now = tet_volumes(np.asarray(positions, dtype=np.float64), tets)
    return int((np.sign(rest) * np.sign(now) < 0).sum())


@functools.lru_cache(maxsize=8)
def _beam_static_tip(cells: tuple, size: tuple, youngs_modulus: float) -> tuple[int, np.ndarray]:
    """The tip vertex of a benchmark beam and its static deflection (m), computed once per beam
    and modulus (both loadings of :func:`bench_time_to_accuracy` share it)."""
    mesh = beam(*cells, size=size)
    fixed = _clamped(mesh)
    tip = int(np.argmax(mesh.vertices[:, 2] + 1e-3 * mesh.vertices[:, 0] + 1e-6 * mesh.vertices[:, 1]))
    return tip, static_tip_deflection(mesh, fixed, youngs_modulus, tip)


def bench_time_to_accuracy(name: str, cells, size, youngs_modulus: float, *, max_time: float = ACCURACY_MAX_TIME,
                           jacobi_steps: int = JACOBI_STEPS, ramp: float = 0.0) -> dict:
    """One case of the time-to-accuracy benchmark: the default solver stepped until settled,
    and the Jacobi-preconditioned CG to the same tolerance for ``jacobi_steps`` steps beside it
    (its cap counted when reached), compared with the default solver's same first steps
    (``same_steps_ms``, ``jacobi_step_ratio``); tip errors relative to the static deflection. Gravity's
    load rises over ``ramp`` (s; 0: at once, see :data:`ACCURACY_RAMPS`), applied as the
    states' external forces, so that a step replays the same recorded launches while it rises."""
    mesh = beam(*cells, size=size)
    fixed = _clamped(mesh)
    gravity = np.array([0.0, -9.81, 0.0])
    model = Model(mesh, density=1000.0, youngs_modulus=youngs_modulus, poisson_ratio=0.3,
                  rayleigh_mass=ACCURACY_DAMPING, gravity=(0.0, 0.0, 0.0), fixed=fixed)
    load = model.particle_load_mass.numpy().astype(np.float64)[:, None] * gravity  # N, what gravity puts on a node
    tip, static = _beam_static_tip(tuple(cells), tuple(size), youngs_modulus)
    solver = SolverCorotational(model)
    ours = _settle(model, solver, tip, static, load, int(round(max_time / ACCURACY_DT)), ramp, jacobi_steps)
    jacobi_solver = SolverCorotational(model, preconditioner="jacobi")
    jacobi = _settle(model, jacobi_solver, tip, static, load, jacobi_steps, ramp, jacobi_steps)
    capped = jacobi["iterations"] >= jacobi_solver.cg_iterations
    return {"name": name, "youngs_modulus": youngs_modulus, "load_ramp_s": ramp, "tets": model.tet_count,
            "nodes": model.particle_count,
            "static_tip_mm": round(1e3 * float(np.linalg.norm(static)), 3), "steps": ours["steps"],
            "settled": ours["settled"], "first_step_ms": round(ours["first_step_ms"], 1),
            "step_ms": round(ours["step_ms"], 2), "cg_iterations": round(ours["iterations"], 2),
            "tip_error": round(ours["tip_error"], 5), "inverted_elements": ours["inverted"],
            "same_steps_ms": round(ours["early_step_ms"], 2),
            "same_steps_cg_iterations": round(ours["early_iterations"], 2),
            "jacobi_step_ms": round(jacobi["step_ms"], 2),
            "jacobi_cg_iterations": round(jacobi["iterations"], 1), "jacobi_capped": bool(capped),
            "jacobi_step_ratio": round(jacobi["step_ms"] / ours["early_step_ms"], 1)}


def _warp_optim_cg(solver: SolverCorotational, dt: float):
    """The same system solved by warp.optim.linear.cg with a LinearOperator (same kernels)."""
    from warp.optim import linear

    from .kernels import cg, tet_p1

    m, n, d = solver.model, solver.model.particle_count, solver.model.device
    scale = solver.stiffness_scale(dt)

    def matvec(x, y, z, alpha, beta):
        wp.launch(cg.operator_mass_axpby, n, inputs=[x, y, solver.inv_diagonal, solver.mass_scale, alpha, beta],
                  outputs=[z], device=d)
        wp.launch(tet_p1.tet_matvec, m.tet_count, device=d,
                  inputs=[m.tet_indices, solver.tet_rotated_gradients, solver.tet_rotation_stiffness,
                          m.tet_stiffness, x, alpha * scale], outputs=[z])
        wp.launch(cg.operator_restore_fixed_rows, n, inputs=[x, y, solver.inv_diagonal, alpha, beta], outputs=[z],
                  device=d)

    def precondition(x, y, z, alpha, beta):
        wp.launch(cg.jacobi_axpby, n, inputs=[x, y, solver.inv_diagonal, alpha, beta], outputs=[z], device=d)

    A = linear.LinearOperator((3 * n, 3 * n), wp.float32, d, matvec)
    M = linear.LinearOperator((3 * n, 3 * n), wp.float32, d, precondition)
    x = wp.zeros(n, dtype=wp.vec3, device=d)
    functor = linear.cg(A, solver.rhs, x, tol=0.0, maxiter=CG_ITERATIONS, M=M, check_every=0,
                        use_cuda_graph=False, run=False)

    def solve():
        x.zero_()
        functor(A, solver.rhs, x)
    return solve


def bench_scene(name: str, cells, size, *, repeats: int = 20, reference_repeats: int = 3, device=None) -> dict:
    """Time one benchmark beam; returns the JSON record of the issue's contract plus details."""
    from .kernels import rotation, tet_p1
    from .reference import ScipyCorotationalStep

    mesh, model, fixed = _scene_model(cells, size, device)
    control = model.control()
    runs = _bent_solvers(model, control)
    steps_s = _alternating_step_seconds(runs, control, repeats)
    step_s = steps_s[None]
    solver, state, scratch = runs[1]  # the kernels' costs below are per element on one thread
    cg_fused_s = _median_seconds(lambda: (solver.launch_cg(), wp.synchronize_device(model.device)), repeats)
    forces_s = _median_seconds(solver.launch_element_pass(state, scratch, DT, record=True).launch, repeats)
    cg_warp_s = _median_seconds(_warp_optim_cg(solver, DT), max(3, repeats // 4))

    # rotation extraction alone, warm-started as in a step, and the SVD it is measured against
    Ds = edge_matrices(state.particle_q.numpy().astype(np.float64), mesh.tets)
    F = wp.array(Ds @ model.tet_poses.numpy(), dtype=wp.mat33, device=model.device)
    R = wp.empty(model.tet_count, dtype=wp.mat33, device=model.device)
    rot = wp.launch(rotation.extract_rotations, model.tet_count, device=model.device, record_cmd=True,
                    inputs=[F, state.tet_rotation, solver.rotation_iterations, solver.rotation_tolerance], outputs=[R])
    svd = wp.launch(rotation.extract_rotations_svd, model.tet_count, device=model.device, record_cmd=True,
                    inputs=[F], outputs=[R])
    rotation_s = _median_seconds(rot.launch, repeats)
    svd_s = _median_seconds(svd.launch, repeats)
    y = wp.zeros(model.particle_count, dtype=wp.vec3, device=model.device)
    matvec = wp.launch(tet_p1.tet_matvec, model.tet_count, device=model.device, record_cmd=True,
                       inputs=[model.tet_indices, solver.tet_rotated_gradients, solver.tet_rotation_stiffness,
                               model.tet_stiffness, state.particle_qd, 1.0], outputs=[y])
    matvec_s = _median_seconds(matvec.launch, repeats * 5)

    ref = ScipyCorotationalStep(mesh.vertices, mesh.tets, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3,
                                rayleigh_mass=0.1, rayleigh_stiffness=0.01, gravity=(9.81, 0.0, 0.0), fixed=fixed)
    xq, vq = state.particle_q.numpy().astype(np.float64), state.particle_qd.numpy().astype(np.float64)
    reference_s = _median_seconds(lambda: ref.step(xq, vq, DT, cg_iterations=CG_ITERATIONS, cg_tolerance=1e-30),
                                  reference_repeats)
    per_element = 1e9 / model.tet_count
    return {
        "name": name,
        "tets": model.tet_count,
        "nodes": model.particle_count,
        "step_ms": round(step_s * 1e3, 3),
        "cpu_threads": runs[None][0].cpu_threads,
        "step_ms_one_thread": round(steps_s[1] * 1e3, 3),
        "reference_step_ms": round(reference_s * 1e3, 3),
        "speedup_vs_reference": round(reference_s / step_s, 2),
        "rotation_ns_per_element": round(rotation_s * per_element, 2),
        "rotation_svd_ns_per_element": round(svd_s * per_element, 2),
        "matvec_ns_per_element": round(matvec_s * per_element, 2),
        "forces_ns_per_element": round(forces_s * per_element, 2),
        "cg_fused_ms": round(cg_fused_s * 1e3, 3),
        "cg_warp_optim_ms": round(cg_warp_s * 1e3, 3),
        "cg_iterations": CG_ITERATIONS,
    }


def bench_quadratic(name: str, cells, size, *, repeats: int = 20, device=None) -> dict:
    """Time a full step with the default solver (converged to its tolerance) and the P2 element
    kernels on a quadratic beam (straight edges), set up like :func:`bench_scene`, and a step of
    the linear beam of the same corners beside it; ``cg_iterations`` is the mean per step."""
    from .kernels import tet_p2
    from .quadratic import to_quadratic

    linear = beam(*cells, size=size)
    mesh = to_quadratic(linear)
    times = {}
    for label, each in (("p2", mesh), ("p1", linear)):
        model = Model(each, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3, rayleigh_mass=0.1,
                      rayleigh_stiffness=0.01, gravity=(9.81, 0.0, 0.0), fixed=_clamped(each), device=device)
        runs = _bent_solvers(model, thread_counts=(None, 1) if label == "p2" else (None,), settings={})
        iterations = []
        for threads, seconds in _alternating_step_seconds(runs, None, repeats, iterations).items():
            times[label, threads] = seconds
        solver, state, scratch = runs[1 if label == "p2" else None]
        threads = runs[None][0].cpu_threads
        if label == "p2":
            forces_s = _median_seconds(solver.launch_element_pass(state, scratch, DT, record=True).launch, repeats)
            y = wp.zeros(model.particle_count, dtype=wp.vec3, device=model.device)
            matvec = wp.launch(tet_p2.tet_matvec, model.tet_count, device=model.device, record_cmd=True,
                               inputs=[model.tet_indices, solver.tet_rotated_gradients,
                                       solver.tet_rotation_stiffness, model.tet_stiffness, state.particle_qd, 1.0],
                               outputs=[y])
            matvec_s = _median_seconds(matvec.launch, repeats * 5)
            p2_nodes, p2_tets, p2_threads = model.particle_count, model.tet_count, threads
            p2_iterations = float(np.mean(iterations))
    per_element = 1e9 / p2_tets
    return {
        "name": name,
        "tets": p2_tets,
        "nodes": p2_nodes,
        "step_ms": round(times["p2", None] * 1e3, 3),
        "steps_per_second": round(1.0 / times["p2", None], 1),
        "cpu_threads": p2_threads,
        "step_ms_one_thread": round(times["p2", 1] * 1e3, 3),
        "forces_ns_per_element": round(forces_s * per_element, 2),
        "matvec_ns_per_element": round(matvec_s * per_element, 2),
        "p1_same_corners_step_ms": round(times["p1", None] * 1e3, 3),
        "cg_iterations": round(p2_iterations, 2),
    }


def _cut_setup(cells, size):
    """Mesh, model, state and the plane of a cut-event benchmark: a beam clamped at x = 0 and
    the plane x = middle cell + CUT_OFFSET, slightly tilted."""
    from .cut import Plane

    mesh = beam(*cells, size=size)
    model = _cut_model(mesh)
    cell = size[0] / cells[0]
    plane = Plane([(cells[0] // 2 + CUT_OFFSET) * cell, 0.0, 0.0], [1.0, 0.02, 0.01])
    return mesh, model, model.state(), plane


def _cut_model(mesh) -> Model:
    """The model of a cut-event benchmark's beam, clamped at x = 0."""
    fixed = mesh.vertices_in_box((-1.0, -1.0, -1.0), (1e-9, 1.0, 1.0))
    return Model(mesh, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3, fixed=fixed)


def bench_cut_event(name: str, cells, size, *, repeats: int = 7) -> dict:
    """Time a cut event: ``Cutter.cut`` (paulus, epsilon 0.1, its local mesh improvement
    included) of a plane crossing about 100 elements, ``TetTopology.to_mesh`` and
    ``Model.rebuild`` in place (the flat arrays laid out again, state carried over, as
    :class:`wcut.scene.Simulation` does). Each repetition cuts a
    fresh copy of the mesh and its model; building them is not timed, nor is collecting its
    garbage (a simulation builds its topology once: Python's full collections,
    which visit every adjacency set, are then rare). Beside it, the same cut by the Python
    operators (``compiled=False``), in the same repetitions. Times are medians over the
    repetitions; ``event_min_ms`` is the fastest event (on a shared machine the spread is wide)."""
    from .cut import Cutter
    from .topology import TetTopology

    mesh, _, _, plane = _cut_setup(cells, size)
    cut_s, rebuild_s, event_s, python_s = [], [], [], []
    for _ in range(repeats + 1):  # the first one warms up
        model = _cut_model(mesh)  # rebuilt in place below: a fresh one each time
        state = model.state()
        topology = TetTopology(mesh, state.particle_q.numpy(), state.particle_qd.numpy())
        cutter = Cutter(topology, method="paulus", epsilon=0.1, compiled=False)
        gc.collect()  # the garbage of building the topology is not the cut's
        start = time.perf_counter()
        cutter.cut(plane)
        python_s.append(time.perf_counter() - start)
        topology = TetTopology(mesh, state.particle_q.numpy(), state.particle_qd.numpy())
        cutter = Cutter(topology, method="paulus", epsilon=0.1)
        gc.collect()
        start = time.perf_counter()
        result = cutter.cut(plane)
        middle = time.perf_counter()
        model.rebuild(topology.to_mesh(), result.change, state, in_place=True)  # as a simulation does
        wp.synchronize_device(model.device)
        end = time.perf_counter()
        cut_s.append(middle - start)
        rebuild_s.append(end - middle)
        event_s.append(end - start)
    return {
        "name": name,
        "tets": mesh.tet_count,
        "nodes": mesh.vertex_count,
        "cut_elements": result.stats.cut_elements,
        "event_ms": round(statistics.median(event_s[1:]) * 1e3, 2),
        "event_min_ms": round(min(event_s[1:]) * 1e3, 2),  # the fastest: what a quiet machine gives
        "cut_ms": round(statistics.median(cut_s[1:]) * 1e3, 2),
        "rebuild_ms": round(statistics.median(rebuild_s[1:]) * 1e3, 2),
        "python_cut_ms": round(statistics.median(python_s[1:]) * 1e3, 2),
    }


def bench_topology_operators(name: str, cells, size, *, repeats: int = 5) -> dict:
    """The 1-4 splits of the elements the cut-event plane crosses (at their centroids), the
    2-3 flips of the faces two of them share, then the general flips of the edges the plane
    crosses, in order, by the Python operators on ``TetTopology`` and by the compiled ones on
    ``TetArrays`` (one launch per batch; the faces' slots found between the launches are not
    timed). The first run compiles."""
    from .topology import TetTopology, TopologyError, face_key, flip23, remove_edge, split_tet
    from .topology.arrays import TetArrays

    mesh, _, _, plane = _cut_setup(cells, size)
    side = plane.signed_distance(mesh.vertices)
    crossed = np.flatnonzero((side[mesh.tets].min(axis=1) < 0) & (side[mesh.tets].max(axis=1) > 0))
    owners: dict = {}
    edges = set()
    for t in crossed.tolist():
        tet = mesh.tets[t].tolist()
        for k in range(4):
            owners.setdefault(face_key(*(tet[:k] + tet[k + 1:])), []).append(t)
        edges |= {(min(a, b), max(a, b)) for i, a in enumerate(tet) for b in tet[i + 1:] if side[a] * side[b] < 0}
    keys = sorted(key for key, around in owners.items() if len(around) == 2)
    edges = sorted(edges)
    weights = np.full((len(crossed), 4), 0.25)
    python_s, compiled_s = [], []
    for _ in range(repeats + 1):
        topo = TetTopology(mesh)
        start = time.perf_counter()
        for t in crossed.tolist():
            split_tet(topo, t, weights[0])
        counts = [0, 0]
        for i, (operator, calls) in enumerate(((flip23, [(key,) for key in keys]), (remove_edge, edges))):
            for args in calls:
                try:
                    operator(topo, *args)
                    counts[i] += 1
                except TopologyError:
                    pass
        python_s.append(time.perf_counter() - start)
        arrays = TetArrays(mesh, device="cpu")
        start = time.perf_counter()
        arrays.split_tets(crossed, weights)
        middle = time.perf_counter()
        tets, live = arrays.tet_indices.numpy(), arrays.live_tets()
        slot_of = {}
        for t in live[np.any(tets[live] >= mesh.vertex_count, axis=1)].tolist():
            tet = tets[t].tolist()
            for k in range(4):
                slot_of[face_key(*(tet[:k] + tet[k + 1:]))] = (t, k)
        faces = [slot_of[key] for key in keys]
        resumed = time.perf_counter()
        compiled = [arrays.flip_faces(faces).count(None), arrays.remove_edges(edges).count(None)]
        compiled_s.append(time.perf_counter() - resumed + middle - start)
    if compiled != counts:
        raise WcutError(f"topology operators bench: {counts} Python flips, {compiled} compiled")
    python_ms, compiled_ms = statistics.median(python_s[1:]) * 1e3, statistics.median(compiled_s[1:]) * 1e3
    return {"name": name, "tets": mesh.tet_count, "splits": len(crossed), "flips": counts[0],
            "general_flips": counts[1], "python_ms": round(python_ms, 3), "compiled_ms": round(compiled_ms, 3),
            "speedup": round(python_ms / compiled_ms, 1)}


def bench_cut_methods(cells, size, epsilons=(0.0, 0.1)) -> list[dict]:
    """Nodes and elements each method adds per cut element for the cut-event plane (thesis
    5.2.1: about 2 nodes per cut element for paulus, 4.2 to 5.6 for Bielser)."""
    from .cut import METHODS, Cutter
    from .topology import TetTopology, connected_components

    mesh, _, _, plane = _cut_setup(cells, size)
    records = []
    for method in METHODS:
        for epsilon in (epsilons if method in ("paulus", "bielser") else epsilons[-1:]):
            topology = TetTopology(mesh)
            stats = Cutter(topology, method=method, epsilon=epsilon).cut(plane).stats
            after = topology.to_mesh()
            records.append({
                "method": method, "epsilon": epsilon, "cut_elements": stats.cut_elements,
                "added_nodes_per_cut_element": round((after.vertex_count - mesh.vertex_count) / stats.cut_elements, 2),
                "added_elements_per_cut_element": round((after.tet_count - mesh.tet_count) / stats.cut_elements, 2),
                "components": int(connected_components(after).max() + 1),
            })
    return records


def run_benchmarks(json_path=None, *, quick: bool = False, progress: bool = True, scenes=SCENES,
                   cut_scenes=CUT_SCENES, p2_scenes=P2_SCENES, ar_frames: int | None = None,
                   blade_frames: int | None = None, accuracy_scenes=SCENES,
                   accuracy_moduli=ACCURACY_MODULI, accuracy_ramps=ACCURACY_RAMPS) -> dict:
    """Run every benchmark scene, print a table and optionally write JSON (atomically).

    ``forces_ns_per_element`` is the once-per-step element kernel (rotation, forces, right-hand
    side, preconditioner); ``cg_fused_ms`` the 20 iterations of our loop and
    ``cg_warp_optim_ms`` the same 20 iterations through ``warp.optim.linear.cg``.
    ``ar_frames``: frames of the augmented-reality loop benchmark (default 90, 20 with
    ``quick``; 0 leaves it out, as does a checkout without ``scenes/ar``). ``blade_frames``:
    frames of ``scenes/organ_cut.toml`` (default: all 90, 30 with ``quick``; 0 leaves it out).
    ``accuracy_ramps``: the times (s) over which the time-to-accuracy cases raise their load,
    each case once per time (0: at once; :data:`ACCURACY_RAMPS`).
    """
    if json_path is not None:
        check_writable(json_path)  # fail now, not after a minute of benchmarks

    def say(line: str) -> None:  # plain lines, so that progress shows in a log as on a terminal
        if progress:
            print(line, file=sys.stderr, flush=True)

    records = []
    for i, (name, cells, size) in enumerate(scenes):
        say(f"[{i + 1}/{len(scenes)}] {name} ...")
        records.append(bench_scene(name, cells, size, repeats=5 if quick else 20, reference_repeats=1 if quick else 3))
        say(f"    step {records[-1]['step_ms']} ms, {records[-1]['cg_iterations']} CG iterations")
    cut_events = []
    for i, (name, cells, size) in enumerate(cut_scenes):
        say(f"[{i + 1}/{len(cut_scenes)}] cut event {name} ...")
        cut_events.append(bench_cut_event(name, cells, size, repeats=2 if quick else 7))
        say(f"    event {cut_events[-1]['event_ms']} ms")
    quadratic = []
    for i, (name, cells, size) in enumerate(p2_scenes):
        say(f"[{i + 1}/{len(p2_scenes)}] quadratic {name} ...")
        quadratic.append(bench_quadratic(name, cells, size, repeats=5 if quick else 20))
        say(f"    step {quadratic[-1]['step_ms']} ms")
    accuracy = []
    cases = [(scene, E, ramp) for ramp in accuracy_ramps for scene in accuracy_scenes for E in accuracy_moduli]
    for i, ((name, cells, size), E, ramp) in enumerate(cases):
        say(f"[{i + 1}/{len(cases)}] time to accuracy {name} E = {E:g} Pa, load over {ramp:g} s ...")
        max_time = ramp + 3.0 if quick else ACCURACY_MAX_TIME
        accuracy.append(bench_time_to_accuracy(name, cells, size, E, max_time=max_time,
                                               jacobi_steps=3 if quick else JACOBI_STEPS, ramp=ramp))
        case = accuracy[-1]
        say(f"    {case['steps']} steps, step {case['step_ms']} ms, tip error {case['tip_error']}")
    result = {"device": str(wp.get_device()), "warp": wp.config.version, "cores": available_cores(), "scenes": records,
              "cut_events": cut_events, "quadratic": quadratic, "time_to_accuracy": accuracy}
    ar_frames = (20 if quick else 90) if ar_frames is None else ar_frames
    if ar_frames and AR_SCENE.exists():
        say("augmented reality ...")
        result["ar_detection"] = bench_detection(repeats=50 if quick else 200)
        result["ar_loop"] = bench_ar_loop(ar_frames)
    blade_frames = (30 if quick else None) if blade_frames is None else blade_frames
    if blade_frames != 0 and BLADE_SCENE.exists():
        say("blade scene ...")
        result["blade_scene"] = bench_blade_scene(blade_frames)
    if cut_scenes:
        result["cut_event_size_ratio"] = round(cut_events[-1]["event_ms"] / cut_events[0]["event_ms"], 2)
        result["cut_methods"] = bench_cut_methods(*cut_scenes[0][1:])
        result["topology_operators"] = bench_topology_operators(*cut_scenes[0], repeats=2 if quick else 5)
    if records:
        _print_table(records)
    if accuracy:
        _print_rows(accuracy, [("name", "time to accuracy"), ("youngs_modulus", "E Pa"), ("load_ramp_s", "load over s"),
                               ("steps", "steps"),
                               ("settled", "settled"), ("first_step_ms", "first step ms"), ("step_ms", "step ms"),
                               ("cg_iterations", "iterations"),
                               ("tip_error", "tip error"), ("inverted_elements", "inverted"),
                               ("same_steps_ms", "same steps ms"), ("jacobi_step_ms", "Jacobi step ms"),
                               ("jacobi_cg_iterations", "Jacobi iterations"), ("jacobi_capped", "capped"),
                               ("jacobi_step_ratio", "Jacobi / ours")])
    if cut_scenes:
        _print_rows(cut_events, [("name", "cut event"), ("tets", "tets"), ("cut_elements", "cut el"),
                                 ("event_ms", "event ms"), ("event_min_ms", "fastest"), ("cut_ms", "cut ms"),
                                 ("rebuild_ms", "rebuild ms"), ("python_cut_ms", "python cut ms")])
        print(f"largest / smallest mesh: {result['cut_event_size_ratio']}x")
        _print_rows(result["cut_methods"], [("method", "method"), ("epsilon", "eps"), ("cut_elements", "cut el"),
                                            ("added_nodes_per_cut_element", "nodes/cut el"),
                                            ("added_elements_per_cut_element", "elements/cut el"),
                                            ("components", "pieces")])
        _print_rows([result["topology_operators"]], [("name", "operators"), ("splits", "1-4 splits"),
                                                     ("flips", "2-3 flips"),
                                                     ("general_flips", "general flips"), ("python_ms", "python ms"),
                                                     ("compiled_ms", "compiled ms"), ("speedup", "speedup")])
    if quadratic:
        _print_rows(quadratic, [("name", "quadratic"), ("tets", "tets"), ("nodes", "nodes"), ("step_ms", "step ms"),
                                ("steps_per_second", "steps/s"), ("cpu_threads", "threads"),
                                ("step_ms_one_thread", "1 thread ms"), ("forces_ns_per_element", "forces ns/el"),
                                ("matvec_ns_per_element", "matvec ns/el"),
                                ("p1_same_corners_step_ms", "P1 same corners ms")])
    if "ar_loop" in result:
        d = result["ar_detection"]
        print(f"cut detection: {d['update_ms']} ms per frame ({d['features']} features, {d['pairs']} pairs)")
        _print_rows([result["ar_loop"]], [("scene", "ar loop"), ("frames", "frames"), ("elements", "tets"),
                                          ("features", "features"), ("fps_mean", "frames/s"),
                                          ("detection_ms_mean", "detection ms"), ("dice_final", "dice")])
    if "blade_scene" in result:
        _print_rows([result["blade_scene"]], [("scene", "blade scene"), ("frames", "frames"), ("elements", "tets"),
                                              ("cut_events", "cut events"), ("step_ms_mean", "step ms"),
                                              ("cut_seconds", "cuts s"), ("cg_iterations", "iterations"),
                                              ("real_time_factor", "real-time factor")])
    if json_path is not None:
        with atomic_path(json_path) as tmp:
            Path(tmp).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {json_path}")
    return result


def _print_table(records) -> None:
    columns = [("name", "scene"), ("tets", "tets"), ("nodes", "nodes"), ("step_ms", "step ms"),
               ("cpu_threads", "threads"), ("step_ms_one_thread", "1 thread ms"),
               ("reference_step_ms", "scipy ms"), ("speedup_vs_reference", "speedup"),
               ("rotation_ns_per_element", "rot ns/el"), ("rotation_svd_ns_per_element", "svd ns/el"),
               ("matvec_ns_per_element", "matvec ns/el"), ("forces_ns_per_element", "forces ns/el"),
               ("cg_fused_ms", "cg fused ms"),
               ("cg_warp_optim_ms", "cg warp.optim ms")]
    _print_rows(records, columns)


def _print_rows(records, columns) -> None:
    rows = [[str(r[key]) for key, _ in columns] for r in records]
    widths = [max([len(title)] + [len(row[i]) for row in rows]) for i, (_, title) in enumerate(columns)]
    print("  ".join(title.rjust(w) for (_, title), w in zip(columns, widths)))
    for row in rows:
        print("  ".join(cell.rjust(w) for cell, w in zip(row, widths)))
