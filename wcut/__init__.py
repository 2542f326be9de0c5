"""wcut: real-time cutting, tearing and fracture of deformable objects with corotational FEM.

The numerical core runs as NVIDIA Warp kernels (``wcut.kernels``) on flat arrays; the
host side (``wcut.mesh``, ``wcut.model``, ``wcut.solver``) follows Newton's split into
Model (rest data), State (positions, velocities) and Control (external inputs).
"""

__version__ = "0.1.0"

from .errors import CaptureError, ExportError, FractureError, MeshError, ModelError, SceneError, SimulationError, WcutError
from .mesh import ShellMesh, TetMesh, beam, l_shape_sheet, precut_sheet, rectangle_sheet

__all__ = [
    "__version__",
    "WcutError",
    "MeshError",
    "ModelError",
    "SceneError",
    "ExportError",
    "SimulationError",
    "FractureError",
    "CaptureError",
    "TetMesh",
    "ShellMesh",
    "beam",
    "rectangle_sheet",
    "l_shape_sheet",
    "precut_sheet",
]
