#!/usr/bin/env python3
"""Regenerate the picture gallery of ``tools/gallery/`` (shown in the README).

Runs three shipped scenes and pictures their last frame with :func:`wcut.picture.render_picture`
(shaded, lit, the wound in dark red, from a camera chosen per scene):

- ``organ_cut.png``: the organ opened by the scalpel, seen from above (``scenes/organ_cut.toml``);
- ``beam_cut.png``: the beam of thesis figure 5.10 cut in two halves (``scenes/beam_cut.toml``);
- ``sheet_crack.png``: the crack across the precut sheet (``scenes/precut_sheet.toml``);

and two results:

- ``ar_overlay.png``: the last frame of ``wcut ar`` on the synthetic capture of
  ``scenes/ar/band_cut_side.toml`` (thesis 7.8.2): the registered model's outline in green,
  its internal structures filled, the tracked features as blue dots (a cut is drawn in red
  in the frames where it is being detected);
- ``cut_nodes.png``: thesis figure 5.11, nodes and condition number while a beam is cut step
  by step, from ``tools/cut_conditioning.py`` (its docstring gives the experiment).

Run::

    .venv/bin/python tools/gallery.py [--out tools/gallery] [--frames N] [--width 640]
    .venv/bin/python tools/gallery.py --scene SCENE.toml --png OUT.png   # one scene (tools/demo)

``--frames`` stops each scene, the AR video and the cut of figure 5.11 early (the latter
then compares epsilon 0 and 0.2 only), and ``--width`` sets the picture width in pixels (the
tests use small values). The whole gallery takes about a minute on two cores.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from wcut.ar.camera import Camera  # noqa: E402
from wcut.cut import TriangleSurface  # noqa: E402
from wcut.io import atomic_path  # noqa: E402
from wcut.picture import render_picture, wound_faces  # noqa: E402
from wcut.scene import Simulation, load_scene  # noqa: E402

#: scene -> (picture, camera eye and target relative to the body's box: fractions of its size
#: from its centre, and the camera's up)
SHOTS = {
    "organ_cut.toml": ("organ_cut.png", (0.15, -0.9, 1.6), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "beam_cut.toml": ("beam_cut.png", (0.45, -1.3, 0.45), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "precut_sheet.toml": ("sheet_crack.png", (0.25, -0.5, 2.2), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
}


def picture(scene_path: Path, shot, frames: int | None, width: int) -> np.ndarray:
    """The last frame of a scene as an RGB image."""
    name, eye, target, up = shot
    sim = Simulation(load_scene(scene_path))
    before = sim.model.mesh
    for _ in range(min(frames or sim.scene.frame_count, sim.scene.frame_count)):
        sim.advance()
    mesh = sim.model.mesh
    x = sim.state.particle_q.numpy().astype(np.float64)
    if hasattr(mesh, "tets"):  # a solid: its boundary, the wound by the rest configuration
        corners = mesh.linear()
        triangles = corners.boundary().triangles
        original = before.linear()
        surface = TriangleSurface(original.vertices, original.boundary().triangles)
        wound = wound_faces(mesh.vertices, triangles, surface, 1e-6 * original.mean_edge_length())
    else:  # a shell: its corner triangles, the crack's lips in the surface colour
        triangles, wound = mesh.triangles[:, :3], None
    lower, upper = x.min(axis=0), x.max(axis=0)
    centre, size = 0.5 * (lower + upper), float(np.max(upper - lower))
    camera = Camera.look_at(centre + size * np.asarray(eye), centre + size * np.asarray(target), up=up,
                            width=width, height=int(0.75 * width), fov_y_deg=40.0)
    return render_picture(camera, x, triangles, wound)


#: the shot of a scene not in SHOTS: from the front, a little above and to the side
DEFAULT_SHOT = (None, (0.3, -1.5, 0.8), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))


#: the synthetic capture of the AR overlay and the picture names of the two results
AR_SCENE = ROOT / "scenes" / "ar" / "band_cut_side.toml"
AR_PNG, NODES_PNG = "ar_overlay.png", "cut_nodes.png"


def ar_overlay(scene: Path, frames: int | None, width: int) -> np.ndarray:
    """The last overlay frame of ``wcut ar`` with cut handling on the capture ``wcut synth``
    makes of ``scene``, scaled to ``width`` pixels, as an RGB image."""
    import cv2

    from wcut.ar.overlay import last_frame
    from wcut.ar.pipeline import run_ar
    from wcut.ar.synth import synthesize

    with tempfile.TemporaryDirectory() as work:
        capture, video = Path(work) / "capture", Path(work) / "overlay.avi"
        synthesize(scene, capture, frames=frames, progress=False)
        run_ar(capture, Path(work) / "model.usdc", overlay=video, progress=False)
        last = last_frame(video)
    if last is None:
        raise RuntimeError(f"{video.name}: no frame could be read back")
    height = max(1, round(last.shape[0] * width / last.shape[1]))
    return cv2.resize(last, (width, height), interpolation=cv2.INTER_AREA)[:, :, ::-1]


def cut_nodes_plot(path: Path, frames: int | None) -> None:
    """Thesis figure 5.11 from ``tools/cut_conditioning.py`` into ``path``."""
    spec = importlib.util.spec_from_file_location("cut_conditioning", ROOT / "tools" / "cut_conditioning.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    with tempfile.TemporaryDirectory() as work:
        argv = ["--out-dir", work, "--quiet"] + (["--quick", "--steps", str(frames)] if frames else [])
        if tool.main(argv) != 0:
            raise RuntimeError("tools/cut_conditioning.py failed (its messages are above)")
        with atomic_path(path) as tmp:
            Path(tmp).write_bytes((Path(work) / tool.PNG_NAME).read_bytes())
    print(f"wrote {path}")


def write_png(image: np.ndarray, path: Path) -> None:
    import cv2

    with atomic_path(path) as tmp:
        cv2.imwrite(tmp, image[:, :, ::-1])
    print(f"wrote {path}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "tools" / "gallery")
    parser.add_argument("--frames", type=int, default=None, help="frames per scene (default: each scene's)")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--scene", type=Path, help="picture this scene only, into --png (tools/demo)")
    parser.add_argument("--png", type=Path, help="the picture of --scene")
    args = parser.parse_args(argv)
    if args.scene is not None:
        shot = SHOTS.get(args.scene.name, DEFAULT_SHOT)
        write_png(picture(args.scene, shot, args.frames, args.width), args.png or args.scene.with_suffix(".png"))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    for scene, shot in SHOTS.items():
        print(f"{scene} ...", file=sys.stderr, flush=True)
        write_png(picture(ROOT / "scenes" / scene, shot, args.frames, args.width), args.out / shot[0])
    print(f"{AR_SCENE.name} (wcut synth, wcut ar) ...", file=sys.stderr, flush=True)
    write_png(ar_overlay(AR_SCENE, args.frames, args.width), args.out / AR_PNG)
    print("thesis figure 5.11 (tools/cut_conditioning.py) ...", file=sys.stderr, flush=True)
    cut_nodes_plot(args.out / NODES_PNG, args.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
