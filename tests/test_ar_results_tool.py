"""tools/ar_results.py (thesis 7.7, 7.8.2): every synthetic scene with and without cut handling."""

from __future__ import annotations

import csv

from conftest import load_tool


def test_a_short_run_writes_both_modes_and_a_figure(tmp_path):
    tool = load_tool("ar_results")
    scene = tool.ROOT / "scenes" / "ar" / "band_cut_side.toml"
    code = tool.main([str(scene), "--out", str(tmp_path), "--frames", "20", "--quiet"])
    with open(tmp_path / tool.CSV_NAME, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert [(r["scene"], r["mode"]) for r in rows] == [("band_cut_side", "cut"), ("band_cut_side", "no-cut")]
    assert all(r["frames"] == "21" and float(r["dice_final"]) > 0.9 for r in rows)
    assert rows[1]["cuts_detected"] == "0" and rows[1]["hausdorff_internal_mean"] == ""
    assert (tmp_path / tool.PNG_NAME).stat().st_size > 10_000
    assert code == (1 if tool.failures([dict(r, dice_final=float(r["dice_final"]), cuts_detected=int(r["cuts_detected"]))
                                        for r in rows]) else 0)


def test_what_the_results_must_show():
    tool = load_tool("ar_results")
    rows = [dict(scene="a", mode="cut", dice_final=0.95, cuts_detected=3),
            dict(scene="a", mode="no-cut", dice_final=0.90, cuts_detected=0),
            dict(scene="b", mode="cut", dice_final=0.90, cuts_detected=1),
            dict(scene="b", mode="no-cut", dice_final=0.92, cuts_detected=0),
            dict(scene="band_control", mode="cut", dice_final=0.99, cuts_detected=2),
            dict(scene="band_control", mode="no-cut", dice_final=0.99, cuts_detected=0)]
    problems = tool.failures(rows)
    assert len(problems) == 2 and problems[0].startswith("b:") and "band_control" in problems[1]


def test_texture_seeds_run_each_scene_with_each_rendering(tmp_path):
    tool = load_tool("ar_results")
    scene = tool.ROOT / "scenes" / "ar" / "band_cut_side.toml"
    code = tool.main([str(scene), "--out", str(tmp_path), "--frames", "3", "--texture-seeds", "3,4", "--quiet"])
    with open(tmp_path / tool.CSV_NAME, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert [(r["mode"], r["texture_seed"]) for r in rows] == [("cut", "3"), ("no-cut", "3"), ("cut", "4"),
                                                             ("no-cut", "4")]
    assert rows[0]["features"] == rows[1]["features"] != rows[2]["features"]  # other features to track
    assert code in (0, 1) and (tmp_path / tool.PNG_NAME).stat().st_size > 10_000


def test_what_the_results_must_show_per_texture_seed():
    tool = load_tool("ar_results")
    rows = [dict(scene="a", mode=mode, texture_seed=seed, dice_final=dice, cuts_detected=0)
            for seed, cut_dice in ((3, 0.95), (4, 0.89)) for mode, dice in (("cut", cut_dice), ("no-cut", 0.90))]
    assert tool.failures(rows) == ["a (texture 4): Dice 0.8900 with cut handling, 0.9000 without"]


def test_a_failed_run_is_a_row_with_its_error_and_the_others_go_on(tmp_path, monkeypatch):
    import wcut.ar.pipeline
    from wcut.errors import SimulationError

    tool = load_tool("ar_results")
    real = wcut.ar.pipeline.run_ar

    def diverging_with_cuts(*args, cut=True, **kwargs):
        if cut:
            raise SimulationError("the model diverged")
        return real(*args, cut=cut, **kwargs)

    monkeypatch.setattr(wcut.ar.pipeline, "run_ar", diverging_with_cuts)
    scene = tool.ROOT / "scenes" / "ar" / "band_cut_side.toml"
    rows, last = tool.run_scene(scene, tmp_path, 2)
    assert rows[0]["error"] == "the model diverged" and rows[0]["dice_final"] is None and last is None
    assert rows[1]["error"] is None and rows[1]["dice_final"] > 0.9
    assert tool.failures(rows) == ["band_cut_side (texture 3): cut run failed: the model diverged"]
    tool.write_png(rows, {("band_cut_side", 3): last}, tmp_path / "failed.png")
    assert (tmp_path / "failed.png").stat().st_size > 10_000
