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

import importlib
import importlib.util

from .errors import (CaptureError, ExportError, FractureError, MeshError, ModelError, SceneError, SimulationError,
                     WcutError)
from .mesh import ShellMesh, TetMesh, beam, l_shape_sheet, precut_sheet, rectangle_sheet

#: the rest of the API, imported when first used: ``import wcut`` stays quick (the command
#: line's ``--version``), the solver, cutter and USD modules load with their first use
_LAZY = {
    "Model": ".model", "State": ".model", "Control": ".model", "SolverCorotational": ".solver",
    "QuadraticTetMesh": ".quadratic", "load_mesh": ".quadratic", "to_quadratic": ".quadratic",
    "Blade": ".blade", "apply_change": ".rebuild", "Cutter": ".cut", "Plane": ".cut", "TriangleSurface": ".cut",
    "TetTopology": ".topology", "TopologyChange": ".topology", "ShellFracture": ".fracture",
    "UsdAnimationWriter": ".usd", "load_scene": ".scene", "run_scene": ".scene",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is not None:
        value = getattr(importlib.import_module(module, __name__), name)
    elif importlib.util.find_spec(f"{__name__}.{name}") is not None:  # a submodule: wcut.model, ...
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'wcut' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


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
