"""The benchmark code runs and reports sane, complete records (speed itself is measured by
``wcut bench``, never asserted in tests)."""

import json

import numpy as np

from wcut.bench import ACCURACY_DT, ACCURACY_RAMPS, load_ramp, run_benchmarks
from wcut.cut import METHODS

KEYS = {"name", "tets", "nodes", "step_ms", "cpu_threads", "step_ms_one_thread", "reference_step_ms", "speedup_vs_reference", "rotation_ns_per_element",
        "matvec_ns_per_element"}
CUT_KEYS = {"name", "tets", "nodes", "cut_elements", "event_ms", "event_min_ms", "cut_ms", "rebuild_ms",
            "python_cut_ms"}
METHOD_KEYS = {"method", "epsilon", "cut_elements", "added_nodes_per_cut_element", "added_elements_per_cut_element",
               "components"}

P2_KEYS = {"name", "tets", "nodes", "step_ms", "steps_per_second", "cpu_threads", "step_ms_one_thread",
           "forces_ns_per_element", "matvec_ns_per_element", "p1_same_corners_step_ms", "cg_iterations"}
ACCURACY_KEYS = {"name", "youngs_modulus", "load_ramp_s", "tets", "nodes", "static_tip_mm", "steps", "settled",
                 "first_step_ms", "step_ms", "cg_iterations", "tip_error", "inverted_elements", "jacobi_step_ms",
                 "same_steps_ms", "same_steps_cg_iterations", "jacobi_cg_iterations", "jacobi_capped",
                 "jacobi_step_ratio"}
BLADE_KEYS = {"scene", "frames", "elements", "cut_events", "step_ms_mean", "cut_seconds", "cg_iterations",
              "real_time_factor"}
#: Two short beams of 1 cm cells with the 4 x 5 cross-section of wcut.bench.CUT_SCENES.
TINY_CUTS = (("tiny_cut", (6, 4, 5), (0.06, 0.04, 0.05)), ("tiny_cut2", (10, 4, 5), (0.10, 0.04, 0.05)))


def test_benchmark_on_a_small_beam_writes_the_contract_json(tmp_path, capsys):
    path = tmp_path / "bench.json"
    tiny = (("tiny", (2, 2, 4), (0.02, 0.02, 0.04)),)
    result = run_benchmarks(path, quick=True, progress=True, scenes=tiny,
                            cut_scenes=TINY_CUTS, p2_scenes=(("tiny_p2", (2, 2, 4), (0.02, 0.02, 0.04)),),
                            ar_frames=6, blade_frames=30, accuracy_scenes=tiny, accuracy_moduli=(1.0e6,))
    written = json.loads(path.read_text())
    assert written == json.loads(json.dumps(result))
    assert written["cores"] >= 1
    (record,) = written["scenes"]
    assert KEYS <= set(record)
    assert record["tets"] == 5 * 2 * 2 * 4 and record["nodes"] == 3 * 3 * 5
    for key in KEYS - {"name", "tets", "nodes"}:
        assert record[key] > 0, key
    assert abs(record["speedup_vs_reference"] - record["reference_step_ms"] / record["step_ms"]) < 0.05 * \
        record["speedup_vs_reference"] + 0.01
    captured = capsys.readouterr()
    out = captured.out
    # progress on stderr gives each measurement's figures as it is made: a run stopped early still tells
    progress = captured.err.splitlines()
    assert f"    step {record['step_ms']} ms, {record['cg_iterations']} CG iterations" in progress
    assert f"    event {written['cut_events'][1]['event_ms']} ms" in progress
    assert f"    step {written['quadratic'][0]['step_ms']} ms" in progress
    assert "tiny" in out and "tiny_cut2" in out and "bielser" in out and "tiny_p2" in out and "cut detection" in out
    detection, loop = written["ar_detection"], written["ar_loop"]
    assert detection["features"] == 500 and 5000 < detection["pairs"] < 9000 and detection["update_ms"] > 0
    assert loop["frames"] == 7 and loop["features"] > 300 and loop["fps_mean"] > 0

    # the organ's scene: its blade enters the body at frame 28
    blade = written["blade_scene"]
    assert set(blade) == BLADE_KEYS and blade["scene"] == "organ_cut" and blade["frames"] == 30
    assert blade["cut_events"] >= 1 and blade["elements"] > 4300 and blade["cg_iterations"] >= 30
    assert blade["step_ms_mean"] > 0 and blade["cut_seconds"] > 0 and blade["real_time_factor"] > 0
    assert "blade scene" in out

    # time to accuracy: the default solver settles on the static deflection of the scipy reference,
    # with the load applied at once and raised smoothly (settled only once it is whole)
    sudden, ramped = written["time_to_accuracy"]
    assert (sudden["load_ramp_s"], ramped["load_ramp_s"]) == ACCURACY_RAMPS
    for accuracy in (sudden, ramped):
        assert set(accuracy) == ACCURACY_KEYS
        assert accuracy["settled"] and accuracy["tip_error"] < 0.01 and accuracy["inverted_elements"] == 0, accuracy
        assert accuracy["static_tip_mm"] > 0 and accuracy["cg_iterations"] >= 1
        assert accuracy["jacobi_cg_iterations"] >= 1 and accuracy["first_step_ms"] > 0 and accuracy["step_ms"] > 0
        # the ratio compares the two solvers over the same steps
        assert accuracy["same_steps_ms"] > 0 and accuracy["same_steps_cg_iterations"] >= 1
        assert abs(accuracy["jacobi_step_ratio"] - accuracy["jacobi_step_ms"] / accuracy["same_steps_ms"]) < 0.051 * \
            accuracy["jacobi_step_ratio"] + 0.051
    assert abs(sudden["static_tip_mm"] - ramped["static_tip_mm"]) < 1e-9
    assert ramped["steps"] > round(ACCURACY_RAMPS[1] / ACCURACY_DT) > sudden["steps"], (ramped, sudden)

    # quadratic elements: same corners, plus one node per edge
    (p2,) = written["quadratic"]
    assert set(p2) == P2_KEYS
    assert p2["tets"] == 5 * 2 * 2 * 4 and p2["nodes"] > 3 * 3 * 5
    for key in P2_KEYS - {"name", "tets", "nodes"}:
        assert p2[key] > 0, key
    assert abs(p2["steps_per_second"] - 1e3 / p2["step_ms"]) < 0.01 * p2["steps_per_second"] + 0.1

    # cut events: the plane crosses the 4 x 5 cross-section, 100 elements, whatever the length
    events = written["cut_events"]
    assert [e["name"] for e in events] == ["tiny_cut", "tiny_cut2"]
    for event, (_, (nx, ny, nz), _) in zip(events, TINY_CUTS):
        assert set(event) == CUT_KEYS
        assert event["tets"] == 5 * nx * ny * nz and event["nodes"] == (nx + 1) * (ny + 1) * (nz + 1)
        assert event["cut_elements"] == 100
        for key in ("event_ms", "event_min_ms", "cut_ms", "rebuild_ms", "python_cut_ms"):
            assert event[key] > 0, key
        assert event["event_min_ms"] <= event["event_ms"]
        # each repetition's event is its cut plus its rebuild, so the medians are ordered too
        assert max(event["cut_ms"], event["rebuild_ms"]) <= event["event_ms"] + 0.01
    assert abs(written["cut_event_size_ratio"] - events[1]["event_ms"] / events[0]["event_ms"]) <= 0.006

    # the methods on the first cut scene's plane
    methods = written["cut_methods"]
    assert all(set(m) == METHOD_KEYS for m in methods)
    assert {m["method"] for m in methods} == set(METHODS)
    by = {(m["method"], m["epsilon"]): m for m in methods}
    assert {("paulus", 0.0), ("paulus", 0.1), ("bielser", 0.0), ("bielser", 0.1)} <= set(by)
    for m in methods:
        assert m["cut_elements"] == 100, m
        assert m["components"] == 2, m  # every method separates the beam
    for epsilon in (0.0, 0.1):
        paulus, bielser = by["paulus", epsilon], by["bielser", epsilon]
        assert 0 < paulus["added_nodes_per_cut_element"] < bielser["added_nodes_per_cut_element"]
        assert 0 < paulus["added_elements_per_cut_element"] < bielser["added_elements_per_cut_element"]
    (delete,) = [m for m in methods if m["method"] == "delete"]
    assert delete["added_nodes_per_cut_element"] == 0.0 and delete["added_elements_per_cut_element"] == -1.0
    (snap,) = [m for m in methods if m["method"] == "snap"]
    assert snap["added_elements_per_cut_element"] == 0.0  # it only moves and duplicates vertices

    # the compiled 1-4 splits, 2-3 flips and general flips against the Python ones, on the same plane
    operators = written["topology_operators"]
    assert operators["name"] == "tiny_cut" and operators["splits"] == 100 and operators["flips"] > 50
    assert operators["general_flips"] > 10
    assert operators["python_ms"] > 0 and operators["compiled_ms"] > 0
    assert abs(operators["speedup"] - operators["python_ms"] / operators["compiled_ms"]) <= 0.06 * operators["speedup"]
    assert "compiled ms" in out


def test_benchmark_without_cut_scenes_reports_no_cut_results(tmp_path):
    result = run_benchmarks(tmp_path / "bench.json", quick=True, progress=False, scenes=(), cut_scenes=(),
                            p2_scenes=(), ar_frames=0, blade_frames=0, accuracy_scenes=())
    assert result["scenes"] == [] and result["cut_events"] == [] and result["quadratic"] == []
    assert result["time_to_accuracy"] == []
    assert "ar_loop" not in result and "ar_detection" not in result and "blade_scene" not in result
    assert "cut_event_size_ratio" not in result and "cut_methods" not in result and "topology_operators" not in result
    assert json.loads((tmp_path / "bench.json").read_text()) == result


def test_benchmark_checks_its_output_before_running(tmp_path, monkeypatch):
    import pytest

    import wcut.bench
    from wcut.errors import ExportError

    (tmp_path / "blocked").write_text("a file where a directory is needed")
    monkeypatch.setattr(wcut.bench, "bench_scene", lambda *a, **k: pytest.fail("benchmarked before the check"))
    monkeypatch.setattr(wcut.bench, "bench_cut_event", lambda *a, **k: pytest.fail("benchmarked before the check"))
    with pytest.raises(ExportError, match="cannot write here"):
        run_benchmarks(tmp_path / "blocked" / "bench.json", progress=False)


def test_the_load_ramp_rises_smoothly_from_nothing_to_the_whole_load():
    times = np.linspace(-1.0, 4.0, 501)
    fractions = np.array([load_ramp(t, 3.0) for t in times])
    assert fractions[times <= 0.0].max() == 0.0 and fractions[times >= 3.0].min() == 1.0
    assert np.all(np.diff(fractions) >= 0.0) and abs(load_ramp(1.5, 3.0) - 0.5) < 1e-15
    # its rate starts and ends at zero: no jolt when the load starts or stops rising
    assert load_ramp(0.01, 3.0) < 1e-4 and 1.0 - load_ramp(2.99, 3.0) < 1e-4
    assert load_ramp(0.0, 0.0) == load_ramp(1e-9, 0.0) == 1.0  # no ramp: the whole load at once
