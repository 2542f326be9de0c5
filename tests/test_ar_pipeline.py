"""Tests of the augmented-reality pipeline end to end: wcut synth, the capture directory,
wcut ar with and without cut handling, the control, a tracking failure and bad captures."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from wcut.ar.capture import Capture
from wcut.ar.pipeline import run_ar
from wcut.ar.synth import synthesize
from wcut.cli import main
from wcut.errors import CaptureError, SceneError

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "ar" / "band_cut_side.toml"
FRAMES = 45  # half of the scene: the slit is open enough to be seen


@pytest.fixture(scope="module")
def side_capture(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("ar") / "band_cut_side"
    result = synthesize(SCENE, directory, frames=FRAMES, progress=False)
    assert result.frames == FRAMES + 1 and result.cut_frames == [2]
    return directory


@pytest.fixture(scope="module")
def control_capture(tmp_path_factory) -> Path:
    """The same band stretched the same way without any cut."""
    root = tmp_path_factory.mktemp("ar_control")
    text = SCENE.read_text()
    start, end = text.index("[cut]"), text.index("[camera]")
    (root / "control.toml").write_text(text[:start] + text[end:])
    synthesize(root / "control.toml", root / "capture", frames=FRAMES, progress=False)
    return root / "capture"


def test_synth_writes_a_complete_capture_with_truth(side_capture):
    d = side_capture
    for name in ("camera.json", "mask.png", "model.vtu", "params.toml", "truth/truth.json", "truth/cut.obj"):
        assert (d / name).is_file(), name
    assert len(list((d / "frames").glob("*.png"))) == FRAMES + 1
    assert len(list((d / "truth" / "masks").glob("*.png"))) == FRAMES + 1
    capture = Capture(d)
    assert capture.frame_count == FRAMES + 1 and capture.model.tet_count == 600
    assert capture.params.springs["stiffness"] == 20.0 and capture.params.detection["tau"] == 10.0
    truth_mask, truth = capture.truth_frame(FRAMES)
    first_mask, _ = capture.truth_frame(0)
    assert capture.mask.sum() < first_mask.sum()  # the region of interest is the outline shrunk
    assert truth_mask.sum() > 1.1 * first_mask.sum()  # stretched
    assert truth["surface_points"][:, 0].max() > 0.14  # 120 mm pulled by 26.4 mm/s for 1.5 s
    assert not list(d.parent.glob(".band_cut_side.*"))  # no work directory left


def test_cut_handling_beats_the_uncut_model(side_capture, tmp_path):
    cut = run_ar(side_capture, tmp_path / "cut.usdc", metrics=tmp_path / "cut.json", progress=False)
    whole = run_ar(side_capture, tmp_path / "whole.usdc", cut=False, progress=False)
    m, w = cut.metrics(), whole.metrics()
    assert m["dice_initial"] > 0.99 and w["dice_initial"] > 0.99  # registered to the first frame
    assert m["cuts_detected"] >= 1 and m["cut_events"] >= 1 and w["cuts_detected"] == 0
    assert m["first_detection_frame"] is not None and m["first_detection_frame"] < FRAMES
    assert m["dice_final"] > w["dice_final"] + 0.003
    assert m["hausdorff_surface_mean"] < w["hausdorff_surface_mean"]
    assert m["hausdorff_surface_max"] < w["hausdorff_surface_max"]
    assert m["nodes_final"] > m["nodes_initial"] and m["springs_removed"] > 0
    written = json.loads((tmp_path / "cut.json").read_text())
    for key in ("dice_final", "hausdorff_surface_mean", "hausdorff_surface_max", "hausdorff_internal_mean",
                "hausdorff_internal_max", "cuts_detected", "first_detection_frame", "detection_ms_mean", "fps_mean"):
        assert key in written
    assert written["dice_final"] == pytest.approx(m["dice_final"])


def test_a_first_cut_point_near_the_side_starts_a_cut_from_it(side_capture):
    from wcut.ar.pipeline import ArTracker

    capture = Capture(side_capture)
    tracker = ArTracker(capture, next(capture.frames()), cut=True)
    radius = tracker.cut_point_radius
    assert tracker.entry_reach == pytest.approx(radius)  # the scene's setting: one radius
    near_side = np.array([0.058, -0.0155, 0.006])  # 4.5 mm inside the band's lower side, on top
    outside, look_ahead = tracker._entry(near_side)
    assert outside[1] == pytest.approx(-0.02 - radius, abs=1e-3) and abs(outside[0] - 0.058) < 1e-3  # samples: 0.37 mm
    assert look_ahead[1] == pytest.approx(-0.0155 + radius, abs=1e-9)  # one radius on, away from it
    assert tracker._entry(np.array([0.058, 0.0, 0.006])) is None  # 20 mm from either side
    tracker.entry_reach = 0.0
    assert tracker._entry(near_side) is None  # off by default


def test_the_stretched_control_gives_no_detection(control_capture, tmp_path):
    result = run_ar(control_capture, tmp_path / "control.usdc", progress=False)
    assert result.cuts_detected == 0 and result.first_detection_frame is None
    assert result.metrics()["dice_final"] > 0.97


def test_a_tracking_failure_loses_the_features_and_the_run_goes_on(side_capture, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(side_capture, broken)
    frames = sorted((broken / "frames").glob("*.png"))
    for path in frames[20:]:  # the view is lost: the camera sees a blank field
        cv2.imwrite(str(path), np.full((360, 480, 3), 40, np.uint8))
    result = run_ar(broken, tmp_path / "broken.usdc", progress=False)
    assert result.frames == FRAMES + 1
    assert result.features_lost > 0.9 * result.features
    error = result.metrics()["feature_error_mean"]  # null once no feature pulls any more
    assert error is None or np.isfinite(error)
    assert np.isfinite(result.metrics()["dice_final"])


def test_command_line_runs_and_reports(side_capture, tmp_path, capsys):
    out, metrics, video = tmp_path / "a.usda", tmp_path / "m.json", tmp_path / "overlay.mp4"
    assert main(["ar", str(side_capture), "-o", str(out), "--metrics", str(metrics), "--overlay", str(video),
                 "--frames", "10", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "frames: 10" in printed and "dice final" in printed
    assert out.is_file() and json.loads(metrics.read_text())["frames"] == 10
    reader = cv2.VideoCapture(str(video))
    count = 0
    while reader.read()[0]:
        count += 1
    assert count == 10


@pytest.mark.parametrize("damage, message", [
    (lambda d: (d / "camera.json").unlink(), "camera.json"),
    (lambda d: (d / "mask.png").unlink(), "mask.png"),
    (lambda d: cv2.imwrite(str(d / "mask.png"), np.zeros((10, 10), np.uint8)), "mask.png"),
    (lambda d: (d / "model.vtu").unlink(), "model"),
    (lambda d: shutil.rmtree(d / "frames"), "no video"),
    (lambda d: (d / "params.toml").write_text("[detection]\ntua = 3\n"), "detection.tua"),
    (lambda d: (d / "params.toml").write_text("[springs]\nstiffness = -1.0\n"), "springs.stiffness"),
    (lambda d: (d / "params.toml").write_text("[solver]\nrotation_stiffness = 1\n"), "solver.rotation_stiffness"),
])
def test_a_broken_capture_is_one_line_naming_the_file_and_nothing_is_written(side_capture, tmp_path, capsys,
                                                                             damage, message):
    broken = tmp_path / "broken"
    shutil.copytree(side_capture, broken, ignore=shutil.ignore_patterns("truth"))
    damage(broken)
    with pytest.raises(CaptureError, match=message):
        Capture(broken)
    out = tmp_path / "out.usdc"
    assert main(["ar", str(broken), "-o", str(out), "--metrics", str(tmp_path / "m.json"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wcut: error:") and message in err[0]
    assert not out.exists() and not (tmp_path / "m.json").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["broken"]


def test_synth_command_and_its_errors(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.read_text().replace("[camera]", "[camera]\nzoom = 2"))
    assert main(["synth", str(bad), "-o", str(tmp_path / "cap"), "--quiet"]) == 2
    assert "camera.zoom" in capsys.readouterr().err
    bad.write_text(SCENE.read_text().replace("[synth]\n", "[nosynth]\n"))
    assert main(["synth", str(bad), "-o", str(tmp_path / "cap"), "--quiet"]) == 2
    assert not (tmp_path / "cap").exists()
    assert main(["synth", str(SCENE), "-o", str(tmp_path / "cap"), "--frames", "2", "--quiet"]) == 0
    assert "cut frames: 2" in capsys.readouterr().out
    assert len(list((tmp_path / "cap" / "frames").glob("*.png"))) == 3


def test_another_texture_seed_renders_the_same_truth_otherwise(tmp_path):
    synthesize(SCENE, tmp_path / "own", frames=2, progress=False)
    synthesize(SCENE, tmp_path / "other", frames=2, progress=False, texture_seed=4)
    own, other = Capture(tmp_path / "own"), Capture(tmp_path / "other")
    (own_mask, own_truth), (other_mask, other_truth) = own.truth_frame(2), other.truth_frame(2)
    assert np.array_equal(own_mask, other_mask)
    assert np.array_equal(own_truth["surface_points"], other_truth["surface_points"])
    first = [cv2.imread(str(c.directory / "frames" / "0000.png")).astype(int) for c in (own, other)]
    on_object = own.truth_frame(0)[0] > 0
    assert np.array_equal(first[0][~on_object], first[1][~on_object])  # the same background
    assert np.abs(first[0] - first[1])[on_object].mean() > 10.0  # another pattern on the object
    with pytest.raises(SceneError, match="texture_seed"):
        synthesize(SCENE, tmp_path / "bad", frames=1, progress=False, texture_seed=4.5)


@pytest.mark.parametrize("scene", sorted((SCENE.parent).glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_synthetic_scene_renders_its_first_frames(scene, tmp_path):
    result = synthesize(scene, tmp_path / "capture", frames=2, progress=False)
    capture = Capture(tmp_path / "capture")
    assert result.frames == 3 and capture.frame_count == 3
    assert 200 <= capture.model.tet_count <= 1000  # the registered model: a few hundred elements
    assert result.truth_elements > capture.model.tet_count  # the truth is finer
    mask, truth = capture.truth_frame(2)
    assert capture.mask.sum() > 2000 and mask.sum() > capture.mask.sum()
    for name, _, _ in capture.internal:
        assert len(truth[f"{name}_triangles"]) > 0


def test_a_diverging_model_is_a_simulation_error(side_capture):
    from wcut.ar.pipeline import ArTracker
    from wcut.errors import SimulationError

    capture = Capture(side_capture)
    frames = capture.frames()
    tracker = ArTracker(capture, next(frames), cut=False)
    tracker.step(next(frames))  # a sound step passes the check
    q = tracker.state.particle_q.numpy()
    q[0] += 1.0e3  # a vertex thrown a kilometre away, finite: check lets it through
    tracker.state.particle_q.assign(q)
    with pytest.raises(SimulationError, match="diverged"):
        tracker._check_bounded()
    rest = tracker.mesh.vertices
    for scale, diverged in ((2.5, False), (15.0, True)):  # the model blown up 2.5 or 15 times about its centre
        tracker.state.particle_q.assign(tracker._rest_centre + scale * (rest - tracker._rest_centre))
        if diverged:
            with pytest.raises(SimulationError, match="diverged"):
                tracker._check_bounded()
        else:
            tracker._check_bounded()


def test_a_look_ahead_near_the_boundary_carries_the_cut_through_it(side_capture):
    from wcut.ar.pipeline import ArTracker

    capture = Capture(side_capture)
    frames = capture.frames()
    tracker = ArTracker(capture, next(frames), cut=True)
    rest = tracker.mesh.vertices
    lower, upper = rest.min(axis=0), rest.max(axis=0)
    radius = tracker.cut_point_radius
    middle = 0.5 * (lower + upper)
    east = np.array([1.0, 0.0, 0.0])
    near = middle.copy()
    near[0] = upper[0] - 0.4 * radius
    assert tracker.boundary_reach == 0.0 and tracker._through_boundary(near, east) is None  # off by default
    tracker.boundary_reach = radius
    assert tracker._through_boundary(middle, east) is None  # the band is wider than two radii
    beyond = tracker._through_boundary(near, 2.0 * east)  # the direction's length does not matter
    step = radius / 20  # BOUNDARY_SAMPLES - 1 steps over the reach
    assert beyond[0] == pytest.approx(upper[0] + radius, abs=1.5 * step)
    np.testing.assert_allclose(beyond[1:], near[1:])

    # A polygon whose look-ahead lands there: the cut goes through and that end is closed.
    detector = tracker.detector
    for x in (near[0] - 2.0 * radius, near[0] - radius):
        tracker._cut(detector._extend(np.array([x, middle[1], middle[2]]), 3))
    assert detector.closed_ends == {(0, False)} and tracker.cut_events == 1
    wound = tracker.mesh.boundary().triangles
    centres = tracker.mesh.vertices[wound].mean(axis=1)
    opened = centres[(centres[:, 0] > lower[0] + 1e-6) & (centres[:, 0] < upper[0] - 1e-6)
                     & (np.abs(centres[:, 1] - middle[1]) < 0.5 * radius)
                     & (centres[:, 2] > lower[2] + 1e-6) & (centres[:, 2] < upper[2] - 1e-6)]
    assert opened[:, 0].max() > upper[0] - 0.5 * radius  # the wound reaches the boundary
