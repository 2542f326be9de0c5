"""Model, State and Control of a corotational tetrahedral object (names as in Newton).

- :class:`Model` holds the rest data as flat ``wp.array``s on one device: rest positions,
  lumped masses, fixed vertices, element connectivity, shape-function gradients, volumes and
  stiffness, attachment springs. It is built from a :class:`wcut.mesh.TetMesh` and material
  parameters, once per topology.
- :class:`State` holds what changes every step: positions, velocities and the element
  rotations (warm start of the polar decomposition).
- :class:`Control` holds what the user drives: external nodal forces and spring targets.

All arrays are public so a user's own Warp kernels can read and write them between steps.
Units are SI: metres, kilograms, seconds, newtons, pascals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .errors import ModelError
from .mesh import TetMesh


def lame_parameters(youngs_modulus, poisson_ratio):
    """Lame parameters (mu, lambda) in Pa from Young's modulus (Pa) and Poisson's ratio."""
    E = np.asarray(youngs_modulus, dtype=np.float64)
    nu = np.asarray(poisson_ratio, dtype=np.float64)
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def _per_element(value, count: int, name: str, lower: float, upper: float, closed_lower: bool) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (count,)) if np.ndim(value) == 0 else \
        np.asarray(value, dtype=np.float64)
    if arr.shape != (count,):
        raise ModelError(f"{name}: expected a number or {count} values (one per element), got shape {arr.shape}")
    low_ok = arr >= lower if closed_lower else arr > lower
    bad = np.flatnonzero(~(np.isfinite(arr) & low_ok & (arr < upper)))
    if len(bad):
        bounds = f"{'[' if closed_lower else '('}{lower}, {upper})"
        raise ModelError(f"{name}: element {bad[0]} has {arr[bad[0]]}, expected a value in {bounds}")
    return np.ascontiguousarray(arr)


@dataclass
class Springs:
    """Attachment springs from points of the object to targets (targets live in Control).

    Attributes:
        indices: (S, 4) vertex indices; unused slots repeat a valid index with weight 0.
        weights: (S, 4) barycentric weights (sum 1 for a point inside an element).
        stiffness: (S,) spring stiffness in N/m.
    """

    indices: np.ndarray
    weights: np.ndarray
    stiffness: np.ndarray

    @staticmethod
    def empty() -> "Springs":
        return Springs(np.zeros((0, 4), np.int32), np.zeros((0, 4)), np.zeros(0))

    @staticmethod
    def at_vertices(vertex_ids, stiffness) -> "Springs":
        """One spring per vertex (weight 1 on the vertex)."""
        ids = np.asarray(vertex_ids, dtype=np.int32).reshape(-1)
        indices = np.repeat(ids[:, None], 4, axis=1)
        weights = np.zeros((len(ids), 4))
        weights[:, 0] = 1.0
        return Springs(indices, weights, np.broadcast_to(np.asarray(stiffness, float), ids.shape).copy())

    @staticmethod
    def at_points(mesh: TetMesh, points, stiffness) -> "Springs":
        """One spring per point, attached by barycentric weights to the element containing it.

        A point outside the mesh attaches to the element whose barycentric coordinates it
        violates least (weights are clamped to [0, 1] and renormalised).
        """
        points = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if points.shape[1] != 3 or not np.isfinite(points).all():
            raise ModelError(f"spring points must be finite (S, 3) coordinates, got shape {points.shape}")
        X = mesh.vertices[mesh.tets]  # (M, 4, 3)
        Dm = np.stack([X[:, 0] - X[:, 3], X[:, 1] - X[:, 3], X[:, 2] - X[:, 3]], axis=2)
        Dm_inv = np.linalg.inv(Dm)
        indices = np.empty((len(points), 4), np.int32)
        weights = np.empty((len(points), 4))
        for s, p in enumerate(points):
            xi = np.einsum("mij,mj->mi", Dm_inv, p - X[:, 3])
            bary = np.concatenate([xi, 1.0 - xi.sum(axis=1, keepdims=True)], axis=1)
            e = int(np.argmax(bary.min(axis=1)))
            w = np.clip(bary[e], 0.0, 1.0)
            indices[s], weights[s] = mesh.tets[e], w / w.sum()
        return Springs(indices, weights, np.broadcast_to(np.asarray(stiffness, float), (len(points),)).copy())

    def __len__(self) -> int:
        return len(self.indices)

    def concatenate(self, other: "Springs") -> "Springs":
        return Springs(np.concatenate([self.indices, other.indices]).astype(np.int32),
                       np.concatenate([self.weights, other.weights]),
                       np.concatenate([self.stiffness, other.stiffness]))


class State:
    """Time-varying data of a model.

    Attributes:
        particle_q: (N,) wp.vec3 positions (m).
        particle_qd: (N,) wp.vec3 velocities (m/s).
        tet_rotation: (M,) wp.quat element rotations of the last step (warm start).
    """

    def __init__(self, model: "Model"):
        self.particle_q = wp.clone(model.particle_q)
        self.particle_qd = wp.clone(model.particle_qd)
        self.tet_rotation = wp.full(model.tet_count, wp.quat_identity(), dtype=wp.quat, device=model.device)


class Control:
    """User inputs applied during a step.

    Attributes:
        particle_f: (N,) wp.vec3 external nodal forces (N), zero by default.
        spring_target: (S,) wp.vec3 targets of the model's springs (m), initially the rest
            positions of the attached points (so springs start relaxed).
    """

    def __init__(self, model: "Model"):
        self.particle_f = wp.zeros(model.particle_count, dtype=wp.vec3, device=model.device)
        self.spring_target = wp.array(model.spring_rest_points, dtype=wp.vec3, device=model.device)


class Model:
    """Rest data of a corotational linear-tetrahedron object.

    Args:
        mesh: the validated tetrahedral mesh (rest configuration, metres).
        density: kg/m^3, a number or one value per element.
        youngs_modulus: Pa, a number or one value per element.
        poisson_ratio: dimensionless in [0, 0.5), a number or one value per element.
        rayleigh_mass: Rayleigh damping coefficient alpha of ``D = alpha M + beta K`` (1/s).
        rayleigh_stiffness: Rayleigh damping coefficient beta (s).
        gravity: acceleration (m/s^2).
        fixed: vertices held in place (Dirichlet): indices or a boolean mask.
        springs: attachment springs (targets in :class:`Control`).
        device: Warp device; defaults to Warp's current device.

    Attributes (all ``wp.array`` on ``device`` unless noted):
        particle_q, particle_qd: (N,) vec3 rest positions (m) and initial velocities (m/s).
        particle_mass: (N,) lumped mass (kg): each element gives a quarter of its mass to each
            of its vertices (the row-sum lumping of thesis 3.2, exact for P1).
        particle_fixed: (N,) int32, 1 for a fixed vertex.
        tet_indices: (M,) vec4i vertex indices, positively oriented.
        tet_shape_gradients: (M,) mat33 ``Dm^{-1}``; row l is grad N_l (1/m), l = 0..2.
        tet_rest_volume: (M,) rest volume (m^3).
        tet_stiffness: (M,) vec2 ``(V mu, V lambda)`` (N*m).
        spring_indices, spring_weights, spring_stiffness: (S,) vec4i, vec4, float (N/m).
        spring_rest_points: host (S, 3) rest positions of the attached points (m).
        surface_triangles: host (F, 3) outward boundary triangles of the mesh.
    """

    def __init__(self, mesh: TetMesh, *, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3,
                 rayleigh_mass: float = 0.0, rayleigh_stiffness: float = 0.0, gravity=(0.0, 0.0, -9.81),
                 fixed=None, springs: Springs | None = None, device=None):
        self.device = wp.get_device(device)
        self.mesh = mesh
        M = mesh.tet_count
        N = mesh.vertex_count
        self.particle_count = N
        self.tet_count = M

        rho = _per_element(density, M, "density", 0.0, np.inf, closed_lower=False)
        E = _per_element(youngs_modulus, M, "youngs_modulus", 0.0, np.inf, closed_lower=False)
        nu = _per_element(poisson_ratio, M, "poisson_ratio", 0.0, 0.5, closed_lower=True)
        for name, value in (("rayleigh_mass", rayleigh_mass), ("rayleigh_stiffness", rayleigh_stiffness)):
            if not (np.isfinite(value) and value >= 0.0):
                raise ModelError(f"{name}: expected a finite value >= 0, got {value}")
        gravity = np.asarray(gravity, dtype=np.float64)
        if gravity.shape != (3,) or not np.isfinite(gravity).all():
            raise ModelError(f"gravity: expected three finite components, got {gravity.tolist()}")
        self.tet_density, self.tet_youngs_modulus, self.tet_poisson_ratio = rho, E, nu
        self.rayleigh_mass = float(rayleigh_mass)
        self.rayleigh_stiffness = float(rayleigh_stiffness)
        self.gravity = wp.vec3(*gravity)

        X = mesh.vertices[mesh.tets]
        Dm = np.stack([X[:, 0] - X[:, 3], X[:, 1] - X[:, 3], X[:, 2] - X[:, 3]], axis=2)
        volume = mesh.volumes()
        mu, lam = lame_parameters(E, nu)
        mass = np.zeros(N)
        np.add.at(mass, mesh.tets.ravel(), np.repeat(rho * volume / 4.0, 4))

        fixed_mask = np.zeros(N, dtype=np.int32)
        if fixed is not None:
            fixed = np.asarray(fixed)
            if fixed.dtype == bool:
                if fixed.shape != (N,):
                    raise ModelError(f"fixed: a mask needs {N} entries, got {fixed.shape}")
                fixed_mask[fixed] = 1
            else:
                fixed = fixed.astype(np.int64).reshape(-1)
                if len(fixed) and (fixed.min() < 0 or fixed.max() >= N):
                    raise ModelError(f"fixed: vertex index out of range 0..{N - 1}")
                fixed_mask[fixed] = 1

        springs = springs if springs is not None else Springs.empty()
        if len(springs):
            idx = np.asarray(springs.indices)
            if idx.min() < 0 or idx.max() >= N:
                raise ModelError(f"springs: vertex index out of range 0..{N - 1}")
            if not (np.isfinite(springs.stiffness).all() and (springs.stiffness >= 0).all()):
                raise ModelError("springs: stiffness must be finite and >= 0")
        self.spring_count = len(springs)
        self.spring_rest_points = np.einsum("sj,sjk->sk", springs.weights, mesh.vertices[springs.indices]) \
            if len(springs) else np.zeros((0, 3))

        d = self.device
        self.particle_q = wp.array(mesh.vertices, dtype=wp.vec3, device=d)
        self.particle_qd = wp.zeros(N, dtype=wp.vec3, device=d)
        self.particle_mass = wp.array(mass, dtype=float, device=d)
        self.particle_fixed = wp.array(fixed_mask, dtype=wp.int32, device=d)
        self.tet_indices = wp.array(mesh.tets.astype(np.int32), dtype=wp.vec4i, device=d)
        self.tet_shape_gradients = wp.array(np.linalg.inv(Dm), dtype=wp.mat33, device=d)
        self.tet_rest_volume = wp.array(volume, dtype=float, device=d)
        self.tet_stiffness = wp.array(np.stack([volume * mu, volume * lam], axis=1), dtype=wp.vec2, device=d)
        self.spring_indices = wp.array(np.asarray(springs.indices, np.int32).reshape(-1, 4), dtype=wp.vec4i, device=d)
        self.spring_weights = wp.array(np.asarray(springs.weights).reshape(-1, 4), dtype=wp.vec4, device=d)
        self.spring_stiffness = wp.array(np.asarray(springs.stiffness, float), dtype=float, device=d)
        self.surface_triangles = mesh.boundary().triangles

    @property
    def fixed_count(self) -> int:
        return int(self.particle_fixed.numpy().sum())

    def state(self) -> State:
        """A new State at rest: positions = rest positions, zero velocity, identity rotations."""
        return State(self)

    def control(self) -> Control:
        """A new Control: zero external forces, spring targets at the attached rest points."""
        return Control(self)
