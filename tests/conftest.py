"""Shared fixtures of the wcut test suite."""

from __future__ import annotations

import importlib.util
import textwrap
from pathlib import Path

import numpy as np
import pytest

import wcut
from wcut.mesh import TetMesh

#: A tiny scene: a 4x2x2 beam clamped at x = 0 (45 vertices, 80 tetrahedra).
TINY_SCENE = """
name = "tiny"

[mesh]
generator = "beam"
cells = [4, 2, 2]
size = [0.2, 0.05, 0.05]

[material]
youngs_modulus = 2.0e5
poisson_ratio = 0.35

[constraints]
fixed_boxes = [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]]]

[solver]
dt = 0.01
cg_iterations = 30

[simulation]
duration = 0.1
fps = 30
"""


@pytest.fixture(scope="session", autouse=True)
def _warp_quiet():
    """Silence Warp's start-up banner and module-load messages for the whole session."""
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    yield


@pytest.fixture
def small_beam():
    """A 4x2x2-cell beam of 0.2 m x 0.05 m x 0.05 m (5 tetrahedra per cell)."""
    return wcut.beam(4, 2, 2, size=(0.2, 0.05, 0.05))


@pytest.fixture
def write_scene():
    """``write_scene(directory, text, name="scene.toml")`` writes a (dedented) scene file; returns its path."""

    def write(directory, text: str, name: str = "scene.toml") -> Path:
        path = Path(directory) / name
        path.write_text(textwrap.dedent(text), encoding="utf-8")
        return path

    return write


@pytest.fixture
def tiny_scene(tmp_path, write_scene):
    """Path of :data:`TINY_SCENE` written to tmp_path as ``tiny.toml``."""
    return write_scene(tmp_path, TINY_SCENE, "tiny.toml")


def run_recording_blade(scene, output, frames=None):
    """run_scene, also returning the scene's blade (its TetTopology is the cut mesh)."""
    import wcut.scene

    blades = []

    class Recorded(wcut.scene._Blade):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            blades.append(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(wcut.scene, "_Blade", Recorded)
        result = wcut.scene.run_scene(scene, output, frames=frames, progress=False)
    (blade,) = blades
    return result, blade


def axis_angle_rotation(axis, angle: float) -> np.ndarray:
    """The rotation (3, 3) by ``angle`` (rad) about ``axis`` (Rodrigues' formula)."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def load_tool(name: str):
    """The script ``tools/<name>.py`` imported as a module (tools are scripts, not a package)."""
    path = Path(__file__).resolve().parent.parent / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Pinhole:
    """A stand-in camera at the origin looking along +z: u = fx x/z + cx, v = fy y/z + cy
    (the duck type of :class:`wcut.ar.camera.Camera` that metrics and overlays use)."""

    def __init__(self, width=160, height=120, fx=200.0, fy=200.0, cx=80.0, cy=60.0):
        self.width, self.height = width, height
        self.fx, self.fy, self.cx, self.cy = fx, fy, cx, cy

    def project(self, points):
        p = np.asarray(points, dtype=np.float64)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * p[:, 0] / z + self.cx
            v = self.fy * p[:, 1] / z + self.cy
        return np.stack([u, v], axis=1), z


# ---- small meshes of the topology tests
def single_tet() -> TetMesh:
    """One tetrahedron."""
    return TetMesh([[0, 0, 0], [1, 0, 0], [0.1, 0.9, 0], [0.2, 0.3, 1.1]], [[0, 1, 2, 3]], name="tet")


def two_tets() -> TetMesh:
    """Two tetrahedra on face (0, 1, 2), apices 3 above and 4 below (a convex bipyramid)."""
    v = [[1, 0, 0], [-0.5, 0.8, 0], [-0.5, -0.8, 0.1], [0.1, 0, 1], [0, 0.1, -1]]
    return TetMesh(v, [[0, 1, 2, 3], [0, 2, 1, 4]], name="pair")


def ring(n: int) -> TetMesh:
    """n tetrahedra around the interior edge (0, 1) along z, vertices 2.. a regular n-gon at z = 0."""
    angles = 2 * np.pi * np.arange(n) / n + 0.1
    v = [[0, 0, -1], [0, 0, 1]] + [[np.cos(a), np.sin(a), 0] for a in angles]
    return TetMesh(v, [[0, 1, 2 + i, 2 + (i + 1) % n] for i in range(n)], name=f"ring({n})")


def nonconvex_pair() -> TetMesh:
    """Two tetrahedra on face (0, 1, 2) whose apices' segment misses that face."""
    v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1], [2, 2, -0.3]]
    return TetMesh(v, [[0, 1, 2, 3], [0, 2, 1, 4]], name="nonconvex")


def pyramid(bend: float = 0.0) -> TetMesh:
    """A square pyramid cut along base diagonal (0, 1); corner 3 raised by ``bend`` (0: coplanar base)."""
    v = [[0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, bend], [0.5, 0.5, 1]]
    return TetMesh(v, [[0, 1, 4, 2], [0, 1, 4, 3]], name=f"pyramid({bend})")


def assert_separates(topo, plane, cutter) -> None:
    """No piece (elements sharing a vertex move together) holds elements on both sides of a
    complete plane cut, judged at ``cutter``'s tolerances."""
    from wcut.cut.separation import plane_separation

    after = topo.to_mesh()
    separation = plane_separation(after.vertices, after.tets, plane, cutter.tolerance,
                                  mean_edge_length=cutter.mean_edge_length, in_plane=cutter.in_plane)
    assert separation.separated, separation.describe()


def element_set(mesh: TetMesh, decimals: int = 12) -> list:
    """The elements as sorted tuples of rounded corner coordinates: equal for two meshes with
    the same elements, whatever the numbering of vertices and elements."""
    corners = np.round(mesh.vertices[mesh.tets], decimals)
    return sorted(tuple(sorted(map(tuple, tet.tolist()))) for tet in corners)


def _strain_energy(F: np.ndarray, volume_mu: np.ndarray, volume_lambda: np.ndarray) -> float:
    """``sum V (mu eps:eps + lambda/2 tr(eps)^2)`` with ``eps = sym(R^T F) - I`` (R the polar
    rotation of F, float64) for deformation gradients F (..., d, d) of square or (3, 2) shape."""
    U, _, Vt = np.linalg.svd(F, full_matrices=False)
    S = np.swapaxes(U @ Vt, -1, -2) @ F
    eps = 0.5 * (S + np.swapaxes(S, -1, -2)) - np.eye(F.shape[-1])
    tr = np.trace(eps, axis1=-2, axis2=-1)
    return float(np.sum(volume_mu * np.sum(eps * eps, axis=(-2, -1)) + 0.5 * volume_lambda * tr ** 2))


def mechanical_energy(model, state) -> float:
    """Kinetic plus elastic energy (J) of a model's state: the corotational strain energy of
    linear or quadratic tetrahedra (at the Gauss points) or of a shell's membrane plus its hinge
    bending energy, computed here in float64 from the model's rest frames."""
    from wcut import p2, shell

    q = state.particle_q.numpy().astype(np.float64)
    energy = 0.5 * float(np.sum(model.particle_mass.numpy()[:, None] * state.particle_qd.numpy().astype(np.float64) ** 2))
    if model.tet_count and model.tet_order == 1:
        x = q[model.tet_indices.numpy()]
        Ds = np.stack([x[:, 0] - x[:, 3], x[:, 1] - x[:, 3], x[:, 2] - x[:, 3]], axis=2)
        c = model.tet_stiffness.numpy().astype(np.float64)
        energy += _strain_energy(Ds @ model.tet_poses.numpy().astype(np.float64), c[:, 0], c[:, 1])
    elif model.tet_count:
        dN = p2.shape_gradients(p2.GAUSS_POINTS)  # (4, 10, 3)
        F = np.einsum("mai,gaj->mgij", q[model.tet_indices.numpy()], dN) @ model.tet_poses.numpy().astype(np.float64)
        c = model.tet_stiffness.numpy().astype(np.float64)
        energy += _strain_energy(F, c[..., 0], c[..., 1])
    if model.tri_count:
        dN = shell.shape_gradients(shell.GAUSS_POINTS)  # (3, 6, 2)
        F = np.einsum("mai,gaj->mgij", q[model.tri_indices.numpy()], dN) @ model.tri_poses.numpy().astype(np.float64)
        c = model.tri_stiffness.numpy().astype(np.float64)
        energy += _strain_energy(F, c[..., 0], c[..., 1])
        energy += shell.bending_energy(q, model.edge_indices.numpy(), model.edge_weights.numpy().astype(np.float64),
                                       model.edge_stiffness.numpy().astype(np.float64),
                                       model.edge_rest_curvature.numpy().astype(np.float64))
    return energy


def assert_listed_product(kernel, model, terms, p: np.ndarray, whole: np.ndarray, seed: int) -> None:
    """``kernel`` (a ``tet_matvec_listed``, scale 0.7) over a random third of the elements and
    over the others adds up to ``whole`` (``tet_matvec``'s product at scale 0.7), and the first
    list's product is nonzero only at the nodes of its elements. ``terms``: the element pass's
    ``"gradients"`` and ``"tangent"``."""
    import warp as wp

    rng = np.random.default_rng(seed)
    listed = np.sort(rng.choice(model.tet_count, model.tet_count // 3, replace=False)).astype(np.int32)
    others = np.setdiff1d(np.arange(model.tet_count), listed).astype(np.int32)
    parts = []
    for elements in (listed, others):
        y = wp.zeros(model.particle_count, dtype=wp.vec3)
        wp.launch(kernel, len(elements),
                  inputs=[wp.array(elements, dtype=wp.int32), model.tet_indices, terms["gradients"], terms["tangent"],
                          model.tet_stiffness, wp.array(p, dtype=wp.vec3), 0.7], outputs=[y])
        parts.append(y.numpy().astype(np.float64))
    touched = np.unique(model.tet_indices.numpy()[listed])
    assert np.abs(parts[0] + parts[1] - whole).max() < 1e-5 * np.abs(whole).max()
    assert np.abs(np.delete(parts[0], touched, axis=0)).max() == 0.0 and np.abs(parts[0][touched]).max() > 0.0
