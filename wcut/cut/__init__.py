"""Cutting: separation surfaces and the remeshing cutter of thesis chapter 5.

- ``surface``: the surfaces a cut follows (plane, bounded polygon, triangulated surface,
  the surface swept by a blade), intersected with mesh edges in the current configuration.
- ``cutter``: :class:`Cutter`, the method of the thesis (``paulus``) and the baselines it is
  compared with (``bielser``, ``snap``, ``delete``), all producing a
  :class:`~wcut.topology.TopologyChange`.
- ``separation``: whether a complete cut separated a mesh, with pieces as a simulation sees
  them (elements sharing a vertex move together).
"""

from .cutter import METHODS, CutError, Cutter, CutResult, CutStats
from .surface import CutSurface, Plane, Polygon, SurfaceError, SweptBlade, TriangleSurface

__all__ = ["METHODS", "Cutter", "CutError", "CutResult", "CutStats", "CutSurface", "Plane", "Polygon",
           "TriangleSurface", "SweptBlade", "SurfaceError"]
