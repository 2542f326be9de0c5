"""A capture directory: what the augmented-reality pipeline reads.

Layout (``wcut synth`` writes one; a real capture needs the same files)::

    video.*  or  frames/*.png    the monocular video (anything OpenCV reads; frames in name order)
    camera.json                  intrinsics and pose (:class:`wcut.ar.camera.Camera`)
    mask.png                     region of interest: features are detected where it is white
    model.*                      the tetrahedral model registered to the first frame (.vtu,
                                 .msh, .vtk, .mesh: anything meshio reads; linear tetrahedra)
    internal/*.obj               optional internal structures (m, the model's rest configuration)
    params.toml                  optional settings (:class:`ArParams`)
    truth/                       optional ground truth (``wcut synth``), for the metrics

Anything missing or inconsistent is a :class:`wcut.CaptureError` naming the file.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np

from ..errors import CaptureError, WcutError
from ..mesh import TetMesh
from ..solver import DEFAULT_CG_ITERATIONS, DEFAULT_CG_TOLERANCE
from .camera import Camera
from .detection import MEASURES
from .features import DETECTORS
from .lifting import LIFTINGS

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

MODEL_SUFFIXES = (".vtu", ".msh", ".vtk", ".mesh")

#: section -> key -> (type, default, lower bound or None, description)
PARAMS_SCHEMA = {
    "video": {"fps": (float, 30.0, 0.0, "frames per second (Hz)")},
    "model": {"density": (float, 1000.0, 0.0, "kg/m^3"), "youngs_modulus": (float, 1.0e5, 0.0, "Pa"),
              "poisson_ratio": (float, 0.3, None, "1"), "rayleigh_mass": (float, 1.0, -1e-300, "1/s"),
              "rayleigh_stiffness": (float, 0.0, -1e-300, "s")},
    "features": {"method": (str, "gftt", DETECTORS, "detector"), "max_count": (int, 500, 0, "features"),
                 "min_distance": (float, 4.0, 0.0, "pixels"), "quality": (float, 0.005, 0.0, "1"),
                 "window": (int, 21, 2, "pixels"), "levels": (int, 3, -1, "pyramid levels"),
                 "fb_threshold": (float, 1.0, 0.0, "pixels"), "jump_factor": (float, 5.0, 0.0, "1"),
                 "jump_floor": (float, 2.0, -1e-300, "pixels")},
    "lifting": {"mode": (str, "plane", LIFTINGS, "plane or surface"),
                "plane_depth": (float, 0.0, -1e-300, "m; 0: the depth of the model's centre")},
    "springs": {"stiffness": (float, 1.0, 0.0, "N/m per feature"),
                "margin": (float, 0.0, -1e-300, "m; 0: the detection's cut_point_radius")},
    "solver": {"substeps": (int, 1, 0, "implicit steps per frame"),
               "cg_iterations": (int, DEFAULT_CG_ITERATIONS, 0, "1; the cap, a safety net (wcut.solver)"),
               "cg_tolerance": (float, DEFAULT_CG_TOLERANCE, -1e-300, "1; relative residual (wcut.solver)"),
               "rotation_stiffness": (bool, True, None, "the tangent's rotation term (wcut.solver)")},
    "detection": {"radius": (float, 0.0, -1e-300, "m; 0: 2.5 times the mean feature spacing"),
                  "cut_point_radius": (float, 0.0, -1e-300, "m; 0: the model's mean edge length"),
                  "tau": (float, 7.0, 0.0, "1"), "min_outliers": (int, 3, 0, "pairs"),
                  "min_measure": (float, 0.0, -1e-300, "m; 0: a fifth of the mean feature spacing"),
                  "measure": (str, "target", MEASURES, "mu2 variant"),
                  "extrusion": (float, 0.0, -1e-300, "m; 0: the model's bounding-box diagonal"),
                  "method": (str, "paulus", ("paulus", "snap", "bielser", "delete"), "cutter"),
                  "epsilon": (float, 0.2, -1e-300, "snapping threshold"),
                  "boundary_reach": (float, 0.0, -1e-300, "cut-point radii; 0: a cut ends at its look-ahead"),
                  "entry_reach": (float, 0.0, -1e-300, "cut-point radii; 0: a polygon's first point cuts nothing"),
                  "max_turn": (float, 45.0, 0.0, "degrees a cut point may turn its polygon")},
}


@dataclasses.dataclass
class ArParams:
    """Settings of the pipeline, one dict per section of :data:`PARAMS_SCHEMA` (defaults filled)."""

    video: dict
    model: dict
    features: dict
    lifting: dict
    springs: dict
    solver: dict
    detection: dict

    @classmethod
    def parse(cls, raw: dict, where: str = "params.toml") -> "ArParams":
        """Check ``raw`` (a parsed params.toml) against :data:`PARAMS_SCHEMA`."""
        unknown = sorted(set(raw) - set(PARAMS_SCHEMA))
        if unknown:
            raise CaptureError(f"{where}: {unknown[0]}: unknown section (expected one of "
                               f"{', '.join(PARAMS_SCHEMA)})")
        sections = {}
        for name, schema in PARAMS_SCHEMA.items():
            table = raw.get(name, {})
            if not isinstance(table, dict):
                raise CaptureError(f"{where}: {name}: expected a table")
            bad = sorted(set(table) - set(schema))
            if bad:
                raise CaptureError(f"{where}: {name}.{bad[0]}: unknown key (expected one of {', '.join(schema)})")
            out = {}
            for key, (kind, default, bound, what) in schema.items():
                value = table.get(key, default)
                out[key] = _checked(value, kind, bound, f"{where}: {name}.{key}", what)
            sections[name] = out
        if not -1.0 < sections["model"]["poisson_ratio"] < 0.5:
            raise CaptureError(f"{where}: model.poisson_ratio: must be in (-1, 0.5)")
        return cls(**sections)


def _checked(value, kind, bound, key: str, what: str):
    if kind is bool:
        if not isinstance(value, bool):
            raise CaptureError(f"{key}: expected true or false ({what}), got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str) or (bound is not None and value not in bound):
            raise CaptureError(f"{key}: expected one of {', '.join(bound)}, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and not isinstance(value, int)):
        raise CaptureError(f"{key}: expected {'an integer' if kind is int else 'a number'} ({what}), got {value!r}")
    if not math.isfinite(value) or (bound is not None and not value > bound):
        raise CaptureError(f"{key}: expected a finite value > {max(bound, 0)} ({what}), got {value!r}")
    return kind(value)


class Capture:
    """A loaded capture directory (see the module docstring).

    Attributes:
        directory: the directory.
        camera: :class:`Camera`.
        mask: (H, W) bool region of interest.
        model: the registered :class:`wcut.TetMesh` (rest = first frame).
        internal: list of (name, vertices (V, 3), triangles (T, 3)).
        params: :class:`ArParams`.
        frame_count: number of frames.
        truth: the ``truth/`` directory, or None.
    """

    def __init__(self, directory):
        self.directory = d = Path(directory)
        if not d.is_dir():
            raise CaptureError(f"{d}: no such capture directory")
        self.camera = Camera.from_json(d / "camera.json")
        self._frames, self._video = self._find_video(d)
        self.mask = self._read_mask(d / "mask.png")
        self.model = self._read_model(d)
        self.internal = self._read_internal(d / "internal")
        params = d / "params.toml"
        raw = {}
        if params.exists():
            try:
                raw = tomllib.loads(params.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
                raise CaptureError(f"params.toml: cannot read: {exc}") from None
        self.params = ArParams.parse(raw)
        truth = d / "truth"
        self.truth = truth if (truth / "masks").is_dir() and (truth / "frames").is_dir() else None

    @staticmethod
    def _find_video(d: Path):
        videos = sorted(p for p in d.glob("video.*") if p.is_file())
        frames = sorted((d / "frames").glob("*.png")) if (d / "frames").is_dir() else []
        if videos and frames:
            raise CaptureError(f"{d}: both {videos[0].name} and frames/*.png: keep one")
        if frames:
            return frames, None
        if videos:
            capture = cv2.VideoCapture(str(videos[0]))
            ok = capture.isOpened()
            capture.release()
            if not ok:
                raise CaptureError(f"{videos[0].name}: OpenCV cannot read this video")
            return None, videos[0]
        raise CaptureError(f"{d}: no video: expected video.* or frames/*.png")

    def _read_mask(self, path: Path) -> np.ndarray:
        if not path.exists():
            raise CaptureError("mask.png: missing (the region of interest, white where features are sought)")
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise CaptureError("mask.png: not an image OpenCV reads")
        if mask.shape != (self.camera.height, self.camera.width):
            raise CaptureError(f"mask.png: {mask.shape[1]}x{mask.shape[0]} pixels, camera.json says "
                               f"{self.camera.width}x{self.camera.height}")
        if not (mask > 127).any():
            raise CaptureError("mask.png: empty region of interest (no white pixel)")
        return mask > 127

    @staticmethod
    def _read_model(d: Path) -> TetMesh:
        found = [p for p in sorted(d.glob("model.*")) if p.suffix in MODEL_SUFFIXES]
        if not found:
            raise CaptureError(f"{d}: no model: expected model{{{','.join(MODEL_SUFFIXES)}}}")
        try:
            return TetMesh.load(found[0])
        except WcutError as exc:
            raise CaptureError(f"{found[0].name}: {exc}") from None

    @staticmethod
    def _read_internal(d: Path) -> list:
        from ..cut.surface import TriangleSurface

        out = []
        for path in sorted(d.glob("*.obj")) if d.is_dir() else []:
            try:
                s = TriangleSurface.load(path)
            except WcutError as exc:
                raise CaptureError(f"internal/{path.name}: {exc}") from None
            out.append((path.stem, s.vertices, s.triangles))
        return out

    @property
    def frame_count(self) -> int:
        if self._frames is not None:
            return len(self._frames)
        capture = cv2.VideoCapture(str(self._video))
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        capture.release()
        return count

    def frames(self):
        """Yield the frames (H, W, 3) uint8 BGR in order; a frame of the wrong size is an error."""
        size = (self.camera.height, self.camera.width)
        if self._frames is not None:
            for path in self._frames:
                image = cv2.imread(str(path), cv2.IMREAD_COLOR)
                if image is None:
                    raise CaptureError(f"frames/{path.name}: not an image OpenCV reads")
                if image.shape[:2] != size:
                    raise CaptureError(f"frames/{path.name}: {image.shape[1]}x{image.shape[0]} pixels, camera.json "
                                       f"says {size[1]}x{size[0]}")
                yield image
            return
        capture = cv2.VideoCapture(str(self._video))
        try:
            index = 0
            while True:
                ok, image = capture.read()
                if not ok:
                    break
                if image.shape[:2] != size:
                    raise CaptureError(f"{self._video.name}: frame {index} is {image.shape[1]}x{image.shape[0]} "
                                       f"pixels, camera.json says {size[1]}x{size[0]}")
                yield image
                index += 1
        finally:
            capture.release()

    def truth_frame(self, index: int) -> tuple[np.ndarray, dict]:
        """The true object mask (H, W) bool and the truth arrays of frame ``index``."""
        if self.truth is None:
            raise CaptureError(f"{self.directory}: no truth/ directory")
        name = f"{index:04d}"
        mask = cv2.imread(str(self.truth / "masks" / f"{name}.png"), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise CaptureError(f"truth/masks/{name}.png: missing or unreadable")
        try:
            with np.load(self.truth / "frames" / f"{name}.npz") as data:
                arrays = {k: data[k] for k in data.files}
        except (OSError, ValueError) as exc:
            raise CaptureError(f"truth/frames/{name}.npz: cannot read: {exc}") from None
        return mask > 127, arrays
