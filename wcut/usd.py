"""USD animation export of triangle surfaces (usd-core / ``pxr``).

:class:`UsdAnimationWriter` records, frame by frame, the boundary triangles of every simulated
object and writes them at the end, atomically, to one USD file.

Layout of the written file::

    #usda 1.0 (or binary crate)
    (
        defaultPrim = "World"             # root_name
        upAxis = "Z"                      # or "Y"
        metersPerUnit = 1                 # meters_per_unit
        startTimeCode = <smallest frame written>
        endTimeCode = <largest frame written>
        timeCodesPerSecond = <fps>
        framesPerSecond = <fps>
    )
    def Xform "World"
    {
        def Mesh "<name>"                 # one prim per object name given to write_frame
        {
            uniform token orientation = "rightHanded"
            uniform token subdivisionScheme = "none"
            point3f[] points.timeSamples = {<frame>: [...], ...}          # every frame
            float3[] extent.timeSamples = {<frame>: [min, max], ...}      # every frame
            int[] faceVertexCounts.timeSamples = {...}                    # only when topology changed
            int[] faceVertexIndices.timeSamples = {...}                   # only when topology changed
            color3f[] primvars:displayColor.timeSamples = {...}           # if colours were given
            (interpolation = "vertex")
        }
    }

One time code is one frame: time code ``t`` is shown at ``t / fps`` seconds. Points are given in
metres and stored in stage units (``points / meters_per_unit``). Triangles are counter-clockwise
seen from outside (outward normals), hence ``orientation = rightHanded``; they are flat
polygons, hence ``subdivisionScheme = none``. The topology attributes are sampled only at the
frames where the triangles differ from the previous ones (the surface changes when an object is
cut), so readers hold the last topology until the next change.

The stage is built in memory; :meth:`UsdAnimationWriter.close` exports it to a temporary file
in the target directory and renames it over the target, so a reader never sees a half-written
file, and a failure (or an exception inside a ``with`` block) leaves no file behind.
"""

from __future__ import annotations

import math
import operator
import pathlib
from dataclasses import dataclass, field

import numpy as np

from wcut.errors import ExportError
from wcut.io import atomic_path

__all__ = ["UsdAnimationWriter", "stress_colors", "validate_usd"]

_EXTENSIONS = (".usd", ".usda", ".usdc")
_UP_AXES = ("Y", "Z")


# --------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------


@dataclass
class _PrimTrack:
    """What the writer remembers about one mesh prim between frames."""

    mesh: object  # pxr.UsdGeom.Mesh
    last_frame: int
    has_colors: bool
    # (frame, triangles) at each frame where the topology was written, oldest first.
    topology: list = field(default_factory=list)


class UsdAnimationWriter:
    """Writes time-sampled triangle-surface animations to one USD file, atomically.

    Parameters
    ----------
    path:
        Output file. The extension chooses the format: ``.usda`` (text), ``.usdc`` or ``.usd``
        (binary crate). Missing parent directories are created by :meth:`close`.
    fps:
        Frames per second; written as both ``timeCodesPerSecond`` and ``framesPerSecond``, so
        that time code ``frame`` plays at ``frame / fps`` seconds.
    up_axis:
        ``"Z"`` or ``"Y"``: the stage's up axis (the points are written as given).
    meters_per_unit:
        Length of one stage unit in metres. Points passed to :meth:`write_frame` are in metres
        and are divided by this value before writing.
    root_name:
        Name of the root ``Xform`` prim (the stage's ``defaultPrim``).

    Use as a context manager: on normal exit the file is written (:meth:`close`); if the block
    raises, nothing is written at all.

    Raises
    ------
    ExportError
        On a bad extension, up axis, fps, unit scale or root name.
    """

    def __init__(
        self,
        path,
        *,
        fps: float = 30.0,
        up_axis: str = "Z",
        meters_per_unit: float = 1.0,
        root_name: str = "World",
    ):
        from pxr import Usd, UsdGeom

        self._path = pathlib.Path(path)
        _check_extension(self._path)
        self._fps = _positive_finite(fps, "fps")
        self._meters_per_unit = _positive_finite(meters_per_unit, "meters_per_unit")
        if up_axis not in _UP_AXES:
            raise ExportError(f"{self._path}: up_axis must be 'Y' or 'Z', got {up_axis!r}")
        _check_identifier(root_name, "root prim name")

        self._stage = Usd.Stage.CreateInMemory()
        UsdGeom.SetStageUpAxis(self._stage, UsdGeom.Tokens.z if up_axis == "Z" else UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(self._stage, self._meters_per_unit)
        self._stage.SetTimeCodesPerSecond(self._fps)
        self._stage.SetFramesPerSecond(self._fps)
        root = UsdGeom.Xform.Define(self._stage, f"/{root_name}")
        self._stage.SetDefaultPrim(root.GetPrim())
        self._root_name = root_name
        self._prims: dict[str, _PrimTrack] = {}
        self._first_frame: int | None = None
        self._last_frame: int | None = None
        self._closed = False
        self._written = False

    @property
    def path(self) -> pathlib.Path:
        """The output path given to the constructor."""
        return self._path

    # -- recording ---------------------------------------------------------------------------

    def write_frame(self, name: str, frame: int, points, triangles, colors=None) -> None:
        """Record the surface of object ``name`` at time code ``frame``.

        Parameters
        ----------
        name:
            Object name; a valid USD identifier. The mesh prim is ``/<root_name>/<name>``.
        frame:
            Integer time code. Frames of one object must be non-decreasing; writing the same
            frame again replaces what was written for it.
        points:
            ``(N, 3)`` float vertex positions in metres, all finite, ``N >= 1``.
        triangles:
            ``(F, 3)`` integer vertex indices in ``[0, N)``, counter-clockwise seen from
            outside.
        colors:
            ``(N, 3)`` finite per-vertex RGB (linear, usually in ``[0, 1]``, e.g. from
            :func:`stress_colors`) or ``None``. An object gets colours on all of its frames or
            on none.

        Raises
        ------
        ExportError
            On a closed writer, an invalid name, a decreasing frame, or malformed / non-finite
            arrays; the message names the object and the frame.
        """
        self._check_open()
        _check_identifier(name, "object name")
        frame = _as_frame(frame, name)
        where = f"object {name!r}, frame {frame}"
        pts = _as_points(points, where)
        tris = _as_triangles(triangles, len(pts), where)
        cols = None if colors is None else _as_colors(colors, len(pts), where)

        track = self._track(name, frame, cols is not None)
        if frame < track.last_frame:
            raise ExportError(
                f"{where}: frames must be non-decreasing, the last frame written was {track.last_frame}"
            )
        if (cols is not None) != track.has_colors:
            raise ExportError(
                f"{where}: colors must be given on every frame of an object or on none"
            )
        self._write_samples(track, frame, pts / self._meters_per_unit, tris, cols)
        track.last_frame = frame
        self._first_frame = frame if self._first_frame is None else min(self._first_frame, frame)
        self._last_frame = frame if self._last_frame is None else max(self._last_frame, frame)

    def _track(self, name: str, frame: int, has_colors: bool) -> _PrimTrack:
        """The track of prim ``name``, defining the mesh on first use."""
        track = self._prims.get(name)
        if track is None:
            track = _PrimTrack(self._define_mesh(name, has_colors), frame, has_colors)
            self._prims[name] = track
        return track

    def _define_mesh(self, name: str, has_colors: bool):
        from pxr import UsdGeom

        mesh = UsdGeom.Mesh.Define(self._stage, f"/{self._root_name}/{name}")
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        if has_colors:
            mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
        return mesh

    def _write_samples(self, track: _PrimTrack, frame: int, pts, tris, cols) -> None:
        from pxr import Usd, Vt

        mesh = track.mesh
        time = Usd.TimeCode(frame)
        pts32 = np.ascontiguousarray(pts, dtype=np.float32)
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts32), time)
        extent = np.stack([pts32.min(axis=0), pts32.max(axis=0)])
        mesh.GetExtentAttr().Set(Vt.Vec3fArray.FromNumpy(extent), time)
        self._write_topology(track, frame, tris)
        if cols is not None:
            values = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(cols, dtype=np.float32))
            mesh.GetDisplayColorPrimvar().Set(values, time)

    def _write_topology(self, track: _PrimTrack, frame: int, tris) -> None:
        """Sample the face attributes at ``frame`` only if the triangles changed."""
        from pxr import Usd, Vt

        counts_attr = track.mesh.GetFaceVertexCountsAttr()
        indices_attr = track.mesh.GetFaceVertexIndicesAttr()
        if track.topology and track.topology[-1][0] == frame:  # rewriting the same frame
            track.topology.pop()
            counts_attr.ClearAtTime(frame)
            indices_attr.ClearAtTime(frame)
        if track.topology and np.array_equal(track.topology[-1][1], tris):
            return
        time = Usd.TimeCode(frame)
        counts_attr.Set(Vt.IntArray.FromNumpy(np.full(len(tris), 3, dtype=np.int32)), time)
        indices_attr.Set(Vt.IntArray.FromNumpy(np.ascontiguousarray(tris.reshape(-1))), time)
        track.topology.append((frame, tris.copy()))

    # -- finishing ---------------------------------------------------------------------------

    def close(self) -> pathlib.Path:
        """Write the file atomically and return its path.

        Sets ``startTimeCode`` / ``endTimeCode`` to the smallest / largest frame written
        (left unset when no frame was written), creates missing parent directories, exports
        to a temporary file next to the target and renames it over the target. Calling
        ``close`` again returns the path without writing.

        Raises
        ------
        ExportError
            If the writer was aborted, a directory cannot be created, or writing fails; no
            temporary file is left behind.
        """
        if self._closed:
            if not self._written:
                raise ExportError(f"{self._path}: the writer was aborted, nothing was written")
            return self._path
        if self._first_frame is not None:
            self._stage.SetStartTimeCode(self._first_frame)
            self._stage.SetEndTimeCode(self._last_frame)
        _export_atomically(self._stage.GetRootLayer(), self._path)
        self._closed = True
        self._written = True
        self._release()
        return self._path

    def abort(self) -> None:
        """Discard everything recorded; nothing is written."""
        self._closed = True
        self._release()

    def _release(self) -> None:
        self._stage = None
        self._prims = {}

    def _check_open(self) -> None:
        if self._closed:
            raise ExportError(f"{self._path}: the writer is closed")

    def __enter__(self) -> "UsdAnimationWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


# --------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------


def _check_extension(path: pathlib.Path) -> None:
    if path.suffix.lower() not in _EXTENSIONS:
        raise ExportError(
            f"{path}: unsupported extension {path.suffix!r}, expected one of {', '.join(_EXTENSIONS)}"
        )


def _positive_finite(value, what: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ExportError(f"{what} must be a number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ExportError(f"{what} must be finite and positive, got {value!r}")
    return value


def _check_identifier(name, what: str) -> None:
    from pxr import Tf

    if not isinstance(name, str) or not Tf.IsValidIdentifier(name):
        raise ExportError(
            f"invalid {what} {name!r}: a USD prim name must start with a letter or '_' and "
            "contain only letters, digits and '_'"
        )


def _as_frame(frame, name: str) -> int:
    if isinstance(frame, bool):
        raise ExportError(f"object {name!r}: frame must be an integer, got {frame!r}")
    try:
        return operator.index(frame)
    except TypeError:
        raise ExportError(f"object {name!r}: frame must be an integer, got {frame!r}") from None


def _as_points(points, where: str) -> np.ndarray:
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ExportError(f"{where}: points are not numeric ({exc})") from None
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise ExportError(f"{where}: points must have shape (N, 3) with N >= 1, got {pts.shape}")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise ExportError(
            f"{where}: {int(bad.sum())} point(s) are NaN or infinite (first: vertex {int(np.argmax(bad))})"
        )
    return pts


def _as_triangles(triangles, n_points: int, where: str) -> np.ndarray:
    tris = np.asarray(triangles)
    if tris.ndim != 2 or tris.shape[1] != 3:
        raise ExportError(f"{where}: triangles must have shape (F, 3), got {tris.shape}")
    if tris.size and tris.dtype.kind not in "iu":
        raise ExportError(f"{where}: triangles must be integers, got dtype {tris.dtype}")
    tris = tris.astype(np.int64, copy=False)
    if tris.size and (tris.min() < 0 or tris.max() >= n_points):
        raise ExportError(
            f"{where}: triangle indices must lie in [0, {n_points}), got [{tris.min()}, {tris.max()}]"
        )
    return tris.astype(np.int32)


def _as_colors(colors, n_points: int, where: str) -> np.ndarray:
    try:
        cols = np.asarray(colors, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ExportError(f"{where}: colors are not numeric ({exc})") from None
    if cols.shape != (n_points, 3):
        raise ExportError(f"{where}: colors must have shape ({n_points}, 3), got {cols.shape}")
    if not np.isfinite(cols).all():
        raise ExportError(f"{where}: colors contain NaN or infinite values")
    return cols


# --------------------------------------------------------------------------------------------
# Atomic write
# --------------------------------------------------------------------------------------------


def _export_atomically(layer, path: pathlib.Path) -> None:
    """Export ``layer`` to a temporary file beside ``path``, then rename it over ``path``."""
    from pxr import Tf

    # A ".usd" file is crate unless told otherwise (USD_DEFAULT_FILE_FORMAT could say usda).
    args = {"format": "usdc"} if path.suffix.lower() == ".usd" else {}
    with atomic_path(path) as tmp:  # keeps the extension, so pxr picks the same file format
        try:
            ok = layer.Export(str(tmp), comment="", args=args)
        except Tf.ErrorException as exc:
            raise ExportError(f"cannot write {path}: {exc}") from None
        if not ok:
            raise ExportError(f"cannot write {path}")


# --------------------------------------------------------------------------------------------
# Colours
# --------------------------------------------------------------------------------------------

# Viridis (sRGB-encoded), sampled at 0, 1/8, ..., 1. Linear interpolation between these nine
# points stays within a few 1/255 of the full map and keeps its monotone lightness.
_VIRIDIS_SRGB = np.array(
    [
        [0.267004, 0.004874, 0.329415],
        [0.282623, 0.140926, 0.457517],
        [0.229739, 0.322361, 0.545706],
        [0.172719, 0.448791, 0.557885],
        [0.127568, 0.566949, 0.550556],
        [0.157851, 0.683765, 0.501686],
        [0.369214, 0.788888, 0.382914],
        [0.678489, 0.863742, 0.189503],
        [0.993248, 0.906157, 0.143936],
    ]
)
_NAN_GREY = 0.5


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def stress_colors(values, vmin=None, vmax=None, *, linear: bool = True) -> np.ndarray:
    """Map scalars (e.g. von Mises stress in Pa) to viridis-like RGB colours.

    Parameters
    ----------
    values:
        ``(N,)`` scalars, in any unit.
    vmin, vmax:
        Values mapped to the lowest / highest colour, in the unit of ``values``; default to
        the smallest / largest finite value. Values outside are clamped (``±inf`` included).
        When ``vmax == vmin`` every finite value gets the lowest colour.
    linear:
        Return linear-light RGB (the default: what USD ``displayColor`` expects, so that the
        rendered colours look like viridis); ``False`` returns the sRGB-encoded map.

    Returns
    -------
    ``(N, 3)`` float32 RGB in ``[0, 1]``. NaN values are grey (0.5, 0.5, 0.5). Lightness
    increases monotonically with the value.

    Raises
    ------
    ExportError
        If ``values`` is not one-dimensional or ``vmin > vmax``.
    """
    vals = np.asarray(values, dtype=np.float64)
    if vals.ndim != 1:
        raise ExportError(f"stress_colors: values must have shape (N,), got {vals.shape}")
    lo, hi = _color_range(vals, vmin, vmax)
    nan = np.isnan(vals)
    span = hi - lo
    with np.errstate(invalid="ignore", over="ignore"):
        t = (vals - lo) / span if span > 0 else (vals > hi).astype(np.float64)
    t = np.clip(np.where(nan, 0.0, t), 0.0, 1.0)
    table = _srgb_to_linear(_VIRIDIS_SRGB) if linear else _VIRIDIS_SRGB
    knots = np.linspace(0.0, 1.0, len(table))
    rgb = np.stack([np.interp(t, knots, table[:, c]) for c in range(3)], axis=1)
    rgb[nan] = _NAN_GREY
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def _color_range(vals: np.ndarray, vmin, vmax) -> tuple[float, float]:
    finite = vals[np.isfinite(vals)]
    lo = float(vmin) if vmin is not None else (float(finite.min()) if finite.size else 0.0)
    hi = float(vmax) if vmax is not None else (float(finite.max()) if finite.size else lo)
    if vmin is None and vmax is not None:
        lo = min(lo, hi)
    if vmax is None and vmin is not None:
        hi = max(lo, hi)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ExportError(f"stress_colors: vmin and vmax must be finite, got {lo} and {hi}")
    if lo > hi:
        raise ExportError(f"stress_colors: vmin ({lo}) is greater than vmax ({hi})")
    return lo, hi


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------

# Validators of the registry that are not run. Empty: all validators registered in usd-core
# 26.11 run in this environment.
_EXCLUDED_VALIDATORS: frozenset[str] = frozenset()


def validate_usd(path, include_warnings: bool = False) -> list[str]:
    """Run every validator registered with OpenUSD's validation framework on a file.

    The registry (``pxr.UsdValidation.ValidationRegistry().GetOrLoadAllValidators()``) holds
    the stage, layer and prim validators of usd-core's schema plugins (core, UsdGeom,
    UsdShade, UsdSkel, UsdLux, UsdMedia, UsdPhysics, UsdUtils); they run on the opened stage
    over all time codes. None is excluded (see ``_EXCLUDED_VALIDATORS``).

    Parameters
    ----------
    path:
        A USD file.
    include_warnings:
        Also report warnings and informational messages (prefixed with their type).

    Returns
    -------
    One message per problem, ``"<validator>: <message>"``, sorted; an empty list means valid.

    Raises
    ------
    ExportError
        If the file cannot be opened or this usd-core has no validation framework.
    """
    try:
        from pxr import UsdValidation
    except ImportError as exc:
        raise ExportError(f"cannot validate {path}: usd-core has no UsdValidation ({exc})") from None
    stage = _open_stage(path)
    registry = UsdValidation.ValidationRegistry()
    validators = [
        v for v in registry.GetOrLoadAllValidators() if v.GetMetadata().name not in _EXCLUDED_VALIDATORS
    ]
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    # Validators run in parallel: sort so that the result does not depend on scheduling.
    return sorted(
        _format_error(e, include_warnings)
        for e in errors
        if _reported(e, include_warnings, UsdValidation.ValidationErrorType)
    )


def _open_stage(path):
    from pxr import Tf, Usd

    path = pathlib.Path(path)
    if not path.is_file():
        raise ExportError(f"cannot validate {path}: no such file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as exc:
        raise ExportError(f"cannot open {path} as USD: {exc}") from None
    if stage is None:
        raise ExportError(f"cannot open {path} as USD")
    return stage


def _reported(error, include_warnings: bool, types) -> bool:
    kind = error.GetType()
    if kind == types.Error:
        return True
    return include_warnings and kind in (types.Warn, types.Info)


def _format_error(error, include_warnings: bool) -> str:
    validator = error.GetValidator()
    name = validator.GetMetadata().name if validator is not None else error.GetName()
    text = f"{name}: {error.GetMessage()}"
    if include_warnings:
        text = f"{error.GetType().displayName}: {text}"
    return text
