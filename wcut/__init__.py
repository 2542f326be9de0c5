"""wcut: real-time cutting, tearing and fracture of deformable objects with corotational FEM.

The numerical core runs as NVIDIA Warp kernels (``wcut.kernels``) on flat arrays; the
host side follows Newton's split into :class:`Model` (rest data), :class:`State` (positions,
velocities) and :class:`Control` (external inputs), stepped by :class:`SolverCorotational`.
A :class:`Blade` cuts a moving body in one's own loop and :func:`apply_change` carries the
simulation over the change; :class:`Cutter` makes single cuts of a :class:`TetTopology`;
:class:`ShellFracture` grows cracks in shells; :class:`UsdAnimationWriter` writes USD;
:func:`load_scene` and :func:`run_scene` run scene files.
"""

__version__ = "0.1.0"

from .blade import Blade
from .cut import Cutter, Plane, TriangleSurface
from .errors import (CaptureError, ExportError, FractureError, MeshError, ModelError, SceneError, SimulationError,
                     WcutError)
from .fracture import ShellFracture
from .mesh import ShellMesh, TetMesh, beam, l_shape_sheet, precut_sheet, rectangle_sheet
from .model import Control, Model, State
from .quadratic import QuadraticTetMesh, load_mesh, to_quadratic
from .rebuild import apply_change
from .scene import load_scene, run_scene
from .solver import SolverCorotational
from .topology import TetTopology, TopologyChange
from .usd import UsdAnimationWriter

__all__ = [
    "__version__",
    # simulation (Newton's names)
    "Model", "State", "Control", "SolverCorotational",
    # meshes
    "TetMesh", "QuadraticTetMesh", "ShellMesh", "load_mesh", "to_quadratic", "beam", "rectangle_sheet",
    "l_shape_sheet", "precut_sheet",
    # topological changes
    "Blade", "apply_change", "Cutter", "Plane", "TriangleSurface", "TetTopology", "TopologyChange",
    "ShellFracture",
    # output and scenes
    "UsdAnimationWriter", "load_scene", "run_scene",
    # errors
    "WcutError", "MeshError", "ModelError", "SceneError", "ExportError", "SimulationError", "FractureError",
    "CaptureError",
]
