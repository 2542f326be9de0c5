"""Internal structures carried by a cut volumetric model (thesis 7.5.4).

An internal structure (a vessel, the calyces of a kidney, a tumour) is a triangle surface
whose vertices are embedded in the model's tetrahedra by barycentric coordinates at the
start, so it follows the model. When a separation surface ``S`` is cut, the triangles ``S``
crosses are deleted (eq. 7.12) and the vertices are embedded again in the remeshed model
(locally: only the points of changed elements move to new elements).

Triangles are tested in the rest configuration of the model: the separation surface is made
there too (it is the material the cut went through), and a triangle of the structure crosses
it at rest exactly when its image crosses the image of ``S``, the map being continuous and
one-to-one before the cut. A triangle is deleted when one of its edges crosses ``S``; a
triangle that ``S`` pierces without crossing an edge (``S`` ends inside it) is kept.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cut.surface import TriangleSurface
from ..errors import CaptureError, WcutError
from .embedding import Embedding


class InternalStructure:
    """A triangle surface embedded in a tetrahedral mesh.

    Args:
        name: what it is called (the file's stem).
        rest_points: (V, 3) vertices (m) in the model's rest configuration.
        triangles: (T, 3) vertex indices.
        embedding: its vertices' :class:`Embedding` in the model.

    Attributes:
        deleted: triangles deleted by cuts so far.
    """

    def __init__(self, name: str, rest_points: np.ndarray, triangles: np.ndarray, embedding: Embedding):
        self.name, self.rest_points, self.triangles, self.embedding = name, rest_points, triangles, embedding
        self.deleted = 0

    @classmethod
    def load(cls, path, rest: np.ndarray, tets: np.ndarray) -> "InternalStructure":
        """Read a Wavefront .obj (m, the model's rest configuration) and embed it in the model
        (``rest`` (N, 3), ``tets`` (M, 4+)). Errors name the file."""
        path = Path(path)
        try:
            surface = TriangleSurface.load(path)
        except WcutError as exc:
            raise CaptureError(f"{path.name}: {exc}") from None
        return cls.embedded(path.stem, surface.vertices, surface.triangles, rest, tets, what=path.name)

    @classmethod
    def embedded(cls, name: str, points, triangles, rest: np.ndarray, tets: np.ndarray,
                 what: str = "internal structure") -> "InternalStructure":
        points = np.asarray(points, dtype=np.float64)
        try:
            embedding = Embedding.locate(rest, tets, points, what=what)
        except WcutError as exc:
            raise CaptureError(f"{what}: not inside the model: {exc}") from None
        return cls(name, points, np.asarray(triangles, dtype=np.int64).reshape(-1, 3), embedding)

    def positions(self, x: np.ndarray, tets: np.ndarray) -> np.ndarray:
        """(V, 3) current vertex positions (m) for the model's vertex positions ``x``."""
        return self.embedding.positions(x, tets)

    def cut(self, surface: TriangleSurface, tolerance: float = 0.0) -> int:
        """Delete the triangles with an edge crossing ``surface`` (rest configuration, m;
        eq. 7.12). Returns how many were deleted."""
        if len(self.triangles) == 0:
            return 0
        a = self.rest_points[self.triangles]  # (T, 3, 3)
        b = np.roll(a, -1, axis=1)
        t, _ = surface.crossings(a.reshape(-1, 3), b.reshape(-1, 3), tolerance)
        gone = ~np.isnan(t).reshape(-1, 3).all(axis=1)
        self.triangles = self.triangles[~gone]
        self.deleted += int(gone.sum())
        return int(gone.sum())

    def after(self, change, rest: np.ndarray, tets: np.ndarray) -> None:
        """Embed the vertices again after a topological change of the model (7.5.4)."""
        self.embedding = self.embedding.after(change, rest, tets)
