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


def element_set(mesh: TetMesh, decimals: int = 12) -> list:
    """The elements as sorted tuples of rounded corner coordinates: equal for two meshes with
    the same elements, whatever the numbering of vertices and elements."""
    corners = np.round(mesh.vertices[mesh.tets], decimals)
    return sorted(tuple(sorted(map(tuple, tet.tolist()))) for tet in corners)
