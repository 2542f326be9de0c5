"""Tests of wcut.usd: USD animation export, validation and the stress colour map."""

from __future__ import annotations

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdGeom  # noqa: E402

from wcut.errors import ExportError  # noqa: E402
from wcut.usd import UsdAnimationWriter, stress_colors, validate_usd  # noqa: E402

# A unit tetrahedron: outward, counter-clockwise seen from outside.
TET_POINTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TET_TRIS = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)
# The tetrahedron "cut": one face removed and one more vertex.
CUT_POINTS = np.vstack([TET_POINTS, [[0.5, 0.5, 0.5]]])
CUT_TRIS = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 4]], dtype=np.int32)

FRAMES = range(2, 7)  # frames 2..6
CUT_FRAME = 5


def _tet_points(frame: int) -> np.ndarray:
    return TET_POINTS * 0.1 + np.array([0.01 * frame, 0.0, 0.002 * frame])


def _write_animation(path, **kwargs):
    """Object 'tet' gets cut at CUT_FRAME and has colours; object 'box' never changes."""
    with UsdAnimationWriter(path, **kwargs) as writer:
        for frame in FRAMES:
            if frame < CUT_FRAME:
                pts, tris = _tet_points(frame), TET_TRIS
            else:
                pts, tris = CUT_POINTS * 0.1, CUT_TRIS
            writer.write_frame("tet", frame, pts, tris, stress_colors(np.arange(len(pts)) * 1e3))
            writer.write_frame("box", frame, TET_POINTS + frame, TET_TRIS)
    return writer


def _leftovers(directory):
    return sorted(p.name for p in directory.iterdir())


@pytest.mark.parametrize("ext", [".usdc", ".usda", ".usd"])
def test_animation_validates_and_reads_back(tmp_path, ext):
    path = tmp_path / f"anim{ext}"
    writer = _write_animation(path, fps=24.0, up_axis="Y", meters_per_unit=1.0)
    assert writer.path == path
    assert _leftovers(tmp_path) == [path.name]
    assert validate_usd(path) == []
    assert validate_usd(path, include_warnings=True) == []

    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/World"
    assert stage.GetStartTimeCode() == FRAMES[0]
    assert stage.GetEndTimeCode() == FRAMES[-1]
    assert stage.GetTimeCodesPerSecond() == 24.0
    assert stage.GetFramesPerSecond() == 24.0

    tet = UsdGeom.Mesh(stage.GetPrimAtPath("/World/tet"))
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/box"))
    assert tet and box
    assert tet.GetOrientationAttr().Get() == UsdGeom.Tokens.rightHanded
    assert tet.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none

    # Exact points (float32) at every frame; extent follows them.
    for frame in FRAMES:
        expected = _tet_points(frame) if frame < CUT_FRAME else CUT_POINTS * 0.1
        got = np.array(tet.GetPointsAttr().Get(frame))
        np.testing.assert_array_equal(got, expected.astype(np.float32))
        extent = np.array(tet.GetExtentAttr().Get(frame))
        np.testing.assert_array_equal(extent, [got.min(axis=0), got.max(axis=0)])
    assert tet.GetPointsAttr().GetTimeSamples() == list(FRAMES)

    # Topology sampled only where the triangles changed.
    assert tet.GetFaceVertexIndicesAttr().GetTimeSamples() == [FRAMES[0], CUT_FRAME]
    assert tet.GetFaceVertexCountsAttr().GetTimeSamples() == [FRAMES[0], CUT_FRAME]
    assert box.GetFaceVertexIndicesAttr().GetTimeSamples() == [FRAMES[0]]
    assert list(tet.GetFaceVertexIndicesAttr().Get(CUT_FRAME - 1)) == TET_TRIS.ravel().tolist()
    assert list(tet.GetFaceVertexIndicesAttr().Get(CUT_FRAME)) == CUT_TRIS.ravel().tolist()
    assert list(tet.GetFaceVertexCountsAttr().Get(FRAMES[-1])) == [3] * len(CUT_TRIS)
    assert list(box.GetFaceVertexIndicesAttr().Get(FRAMES[-1])) == TET_TRIS.ravel().tolist()

    # Colours: vertex primvar on 'tet' only.
    color = UsdGeom.PrimvarsAPI(tet).GetPrimvar("displayColor")
    assert color.IsDefined()
    assert color.GetInterpolation() == UsdGeom.Tokens.vertex
    assert color.GetAttr().GetTimeSamples() == list(FRAMES)
    np.testing.assert_allclose(
        np.array(color.Get(CUT_FRAME)), stress_colors(np.arange(5) * 1e3), rtol=0, atol=1e-7
    )
    assert not UsdGeom.PrimvarsAPI(box).GetPrimvar("displayColor").HasAuthoredValue()


def test_format_follows_extension(tmp_path):
    _write_animation(tmp_path / "a.usda")
    _write_animation(tmp_path / "a.usdc")
    _write_animation(tmp_path / "a.usd")
    assert (tmp_path / "a.usda").read_bytes().startswith(b"#usda 1.0")
    assert (tmp_path / "a.usdc").read_bytes().startswith(b"PXR-USDC")
    assert (tmp_path / "a.usd").read_bytes().startswith(b"PXR-USDC")


def test_meters_per_unit_and_root_name(tmp_path):
    path = tmp_path / "cm.usda"
    with UsdAnimationWriter(path, meters_per_unit=0.01, root_name="Scene") as writer:
        writer.write_frame("tet", 0, TET_POINTS * 0.1, TET_TRIS)
    assert validate_usd(path) == []
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert stage.GetDefaultPrim().GetPath() == "/Scene"
    points = np.array(UsdGeom.Mesh.Get(stage, "/Scene/tet").GetPointsAttr().Get(0))
    np.testing.assert_allclose(points, TET_POINTS * 10.0)  # 0.1 m = 10 cm


def test_creates_parent_directories(tmp_path):
    path = tmp_path / "a" / "b" / "out.usdc"
    _write_animation(path)
    assert path.is_file()
    assert validate_usd(path) == []


def test_overwrites_existing_file(tmp_path):
    path = tmp_path / "anim.usda"
    path.write_text("not usd at all")
    with UsdAnimationWriter(path) as writer:
        writer.write_frame("tet", 7, TET_POINTS, TET_TRIS)
    assert path.read_text().startswith("#usda 1.0")
    assert Usd.Stage.Open(str(path)).GetStartTimeCode() == 7
    assert _leftovers(tmp_path) == ["anim.usda"]


def test_exception_in_with_block_writes_nothing(tmp_path):
    path = tmp_path / "anim.usdc"
    with pytest.raises(RuntimeError, match="boom"):
        with UsdAnimationWriter(path) as writer:
            writer.write_frame("tet", 0, TET_POINTS, TET_TRIS)
            raise RuntimeError("boom")
    assert _leftovers(tmp_path) == []
    with pytest.raises(ExportError):
        writer.close()


def test_exception_in_with_block_keeps_existing_file(tmp_path):
    path = tmp_path / "anim.usda"
    path.write_text("old")
    with pytest.raises(ExportError):
        with UsdAnimationWriter(path) as writer:
            writer.write_frame("tet", 0, TET_POINTS, TET_TRIS)
            writer.write_frame("tet", 1, TET_POINTS, TET_TRIS + 10)
    assert path.read_text() == "old"
    assert _leftovers(tmp_path) == ["anim.usda"]


def test_failed_export_leaves_no_temp_file(tmp_path):
    target = tmp_path / "anim.usda"
    target.mkdir()  # os.replace cannot put a file over a directory
    writer = UsdAnimationWriter(target)
    writer.write_frame("tet", 0, TET_POINTS, TET_TRIS)
    with pytest.raises(ExportError, match="cannot write"):
        writer.close()
    assert _leftovers(tmp_path) == ["anim.usda"]
    assert target.is_dir() and not any(target.iterdir())


def test_close_is_idempotent_and_writer_closed_afterwards(tmp_path):
    writer = UsdAnimationWriter(tmp_path / "a.usda")
    writer.write_frame("tet", 0, TET_POINTS, TET_TRIS)
    assert writer.close() == tmp_path / "a.usda"
    assert writer.close() == tmp_path / "a.usda"
    with pytest.raises(ExportError, match="closed"):
        writer.write_frame("tet", 1, TET_POINTS, TET_TRIS)


def test_same_frame_rewritten_replaces_topology(tmp_path):
    path = tmp_path / "a.usda"
    with UsdAnimationWriter(path) as writer:
        writer.write_frame("tet", 0, TET_POINTS, TET_TRIS)
        writer.write_frame("tet", 1, TET_POINTS, TET_TRIS[:3])
        writer.write_frame("tet", 1, TET_POINTS, TET_TRIS)  # back to the frame-0 topology
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh.Get(stage, "/World/tet")
    assert mesh.GetFaceVertexIndicesAttr().GetTimeSamples() == [0]
    assert mesh.GetFaceVertexCountsAttr().GetTimeSamples() == [0]


@pytest.mark.parametrize("name", ["bad.usdz", "bad.obj", "bad", "bad.usda.tmp"])
def test_bad_extension(tmp_path, name):
    with pytest.raises(ExportError, match="extension"):
        UsdAnimationWriter(tmp_path / name)


@pytest.mark.parametrize(
    "kwargs", [{"up_axis": "X"}, {"up_axis": "z"}, {"fps": 0.0}, {"fps": float("nan")},
               {"meters_per_unit": -1.0}, {"root_name": "1World"}]
)
def test_bad_constructor_arguments(tmp_path, kwargs):
    with pytest.raises(ExportError):
        UsdAnimationWriter(tmp_path / "a.usda", **kwargs)


def _write_one(tmp_path, name="tet", frame=0, points=TET_POINTS, tris=TET_TRIS, colors=None):
    writer = UsdAnimationWriter(tmp_path / "a.usda")
    writer.write_frame(name, frame, points, tris, colors)


def test_nan_point_names_object_and_frame(tmp_path):
    points = TET_POINTS.copy()
    points[2, 1] = np.nan
    with pytest.raises(ExportError, match=r"'tet', frame 3.*NaN"):
        _write_one(tmp_path, frame=3, points=points)
    points[2, 1] = np.inf
    with pytest.raises(ExportError, match="infinite"):
        _write_one(tmp_path, points=points)


@pytest.mark.parametrize("bad", [4, -1])
def test_triangle_index_out_of_range(tmp_path, bad):
    tris = TET_TRIS.copy()
    tris[1, 2] = bad
    with pytest.raises(ExportError, match=r"'tet', frame 0.*\[0, 4\)"):
        _write_one(tmp_path, tris=tris)


@pytest.mark.parametrize(
    "points, tris",
    [
        (TET_POINTS[:, :2], TET_TRIS),
        (TET_POINTS[:0], np.zeros((0, 3), dtype=np.int32)),
        (TET_POINTS, TET_TRIS[:, :2]),
        (TET_POINTS, TET_TRIS.astype(np.float64)),
    ],
)
def test_bad_shapes(tmp_path, points, tris):
    with pytest.raises(ExportError):
        _write_one(tmp_path, points=points, tris=tris)


def test_bad_colors(tmp_path):
    with pytest.raises(ExportError, match=r"colors must have shape \(4, 3\)"):
        _write_one(tmp_path, colors=np.zeros((3, 3)))
    with pytest.raises(ExportError, match="NaN"):
        _write_one(tmp_path, colors=np.full((4, 3), np.nan))


def test_colors_on_all_frames_or_none(tmp_path):
    writer = UsdAnimationWriter(tmp_path / "a.usda")
    writer.write_frame("tet", 0, TET_POINTS, TET_TRIS, np.zeros((4, 3)))
    with pytest.raises(ExportError, match="colors"):
        writer.write_frame("tet", 1, TET_POINTS, TET_TRIS)


@pytest.mark.parametrize("name", ["1tet", "a-b", "a/b", "", "with space", None])
def test_invalid_prim_name(tmp_path, name):
    with pytest.raises(ExportError, match="invalid object name"):
        _write_one(tmp_path, name=name)


def test_decreasing_frame(tmp_path):
    writer = UsdAnimationWriter(tmp_path / "a.usda")
    writer.write_frame("tet", 5, TET_POINTS, TET_TRIS)
    writer.write_frame("tet", 5, TET_POINTS, TET_TRIS)  # equal is allowed
    writer.write_frame("other", 1, TET_POINTS, TET_TRIS)  # per prim
    with pytest.raises(ExportError, match=r"'tet', frame 4.*non-decreasing"):
        writer.write_frame("tet", 4, TET_POINTS, TET_TRIS)


@pytest.mark.parametrize("frame", [1.5, "3", True])
def test_non_integer_frame(tmp_path, frame):
    with pytest.raises(ExportError, match="integer"):
        _write_one(tmp_path, frame=frame)


def test_validate_usd_reports_errors(tmp_path):
    path = tmp_path / "bare.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Mesh.Define(stage, "/M")
    stage.Save()
    errors = validate_usd(path)
    assert any("upAxis" in e for e in errors)
    assert any("metersPerUnit" in e for e in errors)
    assert any("defaultPrim" in e for e in errors)
    with pytest.raises(ExportError, match="no such file"):
        validate_usd(tmp_path / "missing.usda")


def _luminance(rgb):
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def test_stress_colors_range_and_monotone():
    values = np.linspace(-3.0, 7.0, 101)
    rgb = stress_colors(values)
    assert rgb.shape == (101, 3) and rgb.dtype == np.float32
    assert rgb.min() >= 0.0 and rgb.max() <= 1.0
    assert np.all(np.diff(_luminance(rgb)) > 0)
    assert np.all(np.diff(_luminance(stress_colors(values, linear=False))) > 0)
    # Default range: the extremes get the end colours.
    np.testing.assert_allclose(rgb[0], stress_colors([0.0, 1.0])[0])
    np.testing.assert_allclose(rgb[-1], stress_colors([0.0, 1.0])[1])
    # Order-independent.
    np.testing.assert_array_equal(stress_colors(values[::-1]), rgb[::-1])


def test_stress_colors_nan_constant_and_clamping():
    rgb = stress_colors([1.0, np.nan, 3.0])
    np.testing.assert_array_equal(rgb[1], [0.5, 0.5, 0.5])
    low, high = stress_colors([0.0, 1.0])
    np.testing.assert_array_equal(rgb[0], low)
    np.testing.assert_array_equal(rgb[2], high)
    np.testing.assert_array_equal(stress_colors([2.0, 2.0, 2.0]), np.tile(low, (3, 1)))
    clamped = stress_colors([-10.0, 0.5, 10.0, np.inf, -np.inf], vmin=0.0, vmax=1.0)
    np.testing.assert_array_equal(clamped[[0, 4]], np.tile(low, (2, 1)))
    np.testing.assert_array_equal(clamped[[2, 3]], np.tile(high, (2, 1)))
    assert np.all(stress_colors([np.nan, np.nan]) == 0.5)
    assert stress_colors([]).shape == (0, 3)
    with pytest.raises(ExportError):
        stress_colors([1.0, 2.0], vmin=2.0, vmax=1.0)
    with pytest.raises(ExportError):
        stress_colors(np.zeros((2, 2)))


def test_written_file_gets_the_usual_permissions(tmp_path):
    import os

    umask = os.umask(0o022)
    try:
        path = tmp_path / "a.usdc"
        with UsdAnimationWriter(path) as writer:
            writer.write_frame("tet", 0, TET_POINTS, TET_TRIS)
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644
