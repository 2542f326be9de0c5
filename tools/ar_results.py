#!/usr/bin/env python3
"""Augmented reality with and without cut handling on the synthetic scenes (thesis 7.7, 7.8.2).

For every synthetic scene (``scenes/ar/*.toml`` by default) this writes the capture with
``wcut synth``, runs ``wcut ar`` on it with cut handling and with ``--no-cut``, and collects
the metrics of both runs: the final Dice coefficient of the model's outline against the
object's (eq. 7.13; the thesis reports 0.952 vs 0.815, 0.964 vs 0.900, 0.951 vs 0.740 and
0.964 vs 0.819 on its silicone bands), the sampled Hausdorff distances of the surface and the
internal structures against the truth (eq. 7.14, table 7.2), the detections, the detection
time and the loop's frame rate.

Run::

    .venv/bin/python tools/ar_results.py [--out out/ar_results] [--frames N] [--texture-seeds 3,4,5]
                                         [--quiet] [SCENE.toml ...]

``--texture-seeds`` renders every scene with each of these texture seeds instead of its own:
the same truth (object, cut, camera) with other features to track, which tells whether the
scene's detection settings hold beyond the rendering they were chosen on.

Writes into ``--out`` (atomically, each file): ``ar_results.csv`` (one row per scene, texture
seed and mode: ``scene, mode, texture_seed, frames, features, dice_final,
hausdorff_surface_mean, hausdorff_surface_max, hausdorff_internal_mean, hausdorff_internal_max,
cuts_detected, first_detection_frame, detection_ms_mean, fps_mean, error``; distances in mm;
``error`` says why a run failed, a diverging model, and the others go on) and ``ar_results.png`` (Dice with and without
cut handling per scene, and the last overlay frame of each run with cut handling). Exit status
0, or 1 when a scene's Dice with cut handling does not beat ``--no-cut`` (the control, whose
name ends in ``control``, must give no detection instead).
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CSV_NAME, PNG_NAME = "ar_results.csv", "ar_results.png"
COLUMNS = ("scene", "mode", "texture_seed", "frames", "features", "dice_final", "hausdorff_surface_mean",
           "hausdorff_surface_max", "hausdorff_internal_mean", "hausdorff_internal_max", "cuts_detected",
           "first_detection_frame", "detection_ms_mean", "fps_mean", "error")
MM = ("hausdorff_surface_mean", "hausdorff_surface_max", "hausdorff_internal_mean", "hausdorff_internal_max")


def run_scene(scene: Path, work: Path, frames: int | None,
              texture_seed: int | None = None) -> tuple[list[dict], np.ndarray]:
    """The two rows of a scene (cut, no-cut) and the last overlay frame of the run with cuts;
    ``texture_seed`` replaces the scene's. A run that fails (a diverging model) gives a row
    with its ``error`` and no metrics, and the other runs go on."""
    from wcut.ar.overlay import last_frame
    from wcut.ar.pipeline import run_ar
    from wcut.ar.synth import load_synth_scene, synthesize
    from wcut.errors import WcutError

    seed = load_synth_scene(scene).synth["texture_seed"] if texture_seed is None else texture_seed
    name = f"{scene.stem}-{seed}"
    capture = work / name
    synthesize(scene, capture, frames=frames, progress=False, texture_seed=seed)
    rows = []
    for mode in ("cut", "no-cut"):
        video = work / f"{name}-{mode}.avi"
        try:
            m = run_ar(capture, work / f"{name}-{mode}.usdc", overlay=video if mode == "cut" else None,
                       cut=mode == "cut", progress=False).metrics()
        except WcutError as error:
            m = {"error": str(error)}
        row = {key: m.get(key) for key in COLUMNS}
        row.update(scene=scene.stem, mode=mode, texture_seed=seed)
        for key in MM:
            row[key] = None if row[key] is None else 1e3 * row[key]
        rows.append(row)
    return rows, last_frame(work / f"{name}-cut.avi")


def _run_name(row: dict) -> str:
    seed = row.get("texture_seed")
    return row["scene"] if seed is None else f"{row['scene']} (texture {seed})"


def failures(rows: list[dict]) -> list[str]:
    """What the results fail to show: cut handling must beat --no-cut, the control must stay
    uncut; per scene and texture seed."""
    out = []
    for scene, seed in dict.fromkeys((r["scene"], r.get("texture_seed")) for r in rows):
        cut, whole = (next(r for r in rows if (r["scene"], r.get("texture_seed"), r["mode"]) == (scene, seed, m))
                      for m in ("cut", "no-cut"))
        name = _run_name(cut)
        failed = [f"{name}: {r['mode']} run failed: {r['error']}" for r in (cut, whole) if r.get("error")]
        if failed:
            out += failed
        elif scene.endswith("control"):
            if cut["cuts_detected"]:
                out.append(f"{name}: {cut['cuts_detected']} detections on the control")
        elif not cut["dice_final"] > whole["dice_final"]:
            out.append(f"{name}: Dice {cut['dice_final']:.4f} with cut handling, {whole['dice_final']:.4f} without")
    return out


def write_csv(rows: list[dict], path: Path) -> None:
    from wcut.io import atomic_path

    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else ("" if v is None else v)) for k, v in r.items()})
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text.getvalue(), encoding="utf-8")


def write_png(rows: list[dict], frames: dict, path: Path) -> None:
    """Dice with and without cut handling per run (scene and texture seed), and the last
    overlay frame of each scene's first run (``frames`` keyed by ``(scene, texture_seed)``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from wcut.io import atomic_path

    runs = list(dict.fromkeys((r["scene"], r.get("texture_seed")) for r in rows))
    scenes = list(dict.fromkeys(scene for scene, _ in runs))
    columns = max(len(scenes), 1)
    fig = plt.figure(figsize=(max(3.2 * columns, 0.9 * len(runs), 6.0), 6.0))
    grid = fig.add_gridspec(2, columns, height_ratios=[1.0, 1.1])
    bars = fig.add_subplot(grid[0, :])
    x = np.arange(len(runs))
    for k, (mode, color) in enumerate((("cut", "tab:green"), ("no-cut", "tab:gray"))):
        values = [next(r["dice_final"] for r in rows
                       if (r["scene"], r.get("texture_seed")) == run and r["mode"] == mode) for run in runs]
        bars.bar(x + (k - 0.5) * 0.38, [np.nan if v is None else v for v in values], 0.38, color=color,
                 label=f"{mode}")
        for xi, v in zip(x, values):
            label, height = ("failed", 1.0) if v is None else (f"{v:.3f}", v)
            bars.text(xi + (k - 0.5) * 0.38, height + 0.002, label, ha="center", fontsize=7)
    several = len(runs) > len(scenes)
    bars.set_xticks(x, [f"{scene}\ntexture {seed}" if several else scene for scene, seed in runs],
                    fontsize=6 if several else 8)
    bars.set_ylim(min((r["dice_final"] for r in rows if r["dice_final"] is not None), default=0.9) - 0.03, 1.01)
    bars.set_ylabel("final Dice (eq. 7.13)")
    bars.legend(fontsize=8, loc="lower right")
    bars.set_title("model outline against the object in the last frame")
    for i, s in enumerate(scenes):
        ax = fig.add_subplot(grid[1, i])
        first = next(run for run in runs if run[0] == s)
        if frames.get(first) is not None:
            ax.imshow(frames[first][:, :, ::-1])
        ax.set_title(f"{s} (cut handling)", fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _seeds(text: str) -> list[int]:
    try:
        return [int(s) for s in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", type=Path, help="synthetic scenes (default: scenes/ar/*.toml)")
    parser.add_argument("--out", type=Path, default=Path("out/ar_results"))
    parser.add_argument("--frames", type=int, default=None, help="frames per scene (default: each scene's)")
    parser.add_argument("--texture-seeds", type=_seeds, default=[None], metavar="N,M,...",
                        help="render each scene with these texture seeds instead of its own")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    scenes = args.scenes or sorted((ROOT / "scenes" / "ar").glob("*.toml"))
    rows, frames = [], {}
    with tempfile.TemporaryDirectory(prefix="wcut-ar-results-") as tmp:
        for scene in scenes:
            for seed in args.texture_seeds:
                if not args.quiet:
                    print(f"{scene.stem} ..." if seed is None else f"{scene.stem}, texture {seed} ...", file=sys.stderr)
                scene_rows, last = run_scene(scene, Path(tmp), args.frames, seed)
                frames[scene.stem, scene_rows[0]["texture_seed"]] = last
                rows += scene_rows
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, args.out / CSV_NAME)
    write_png(rows, frames, args.out / PNG_NAME)
    if not args.quiet:
        for r in rows:
            print("  ".join(f"{k}={r[k]:.4g}" if isinstance(r[k], float) else f"{k}={r[k]}" for k in COLUMNS))
    problems = failures(rows)
    for p in problems:
        print(f"not shown: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
