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
