#!/usr/bin/env python3
"""Regenerate the picture gallery of ``tools/gallery/`` (shown in the README).

Runs three shipped scenes and pictures their last frame with :func:`wcut.picture.render_picture`
(shaded, lit, the wound in dark red, from a camera chosen per scene):

- ``organ_cut.png``: the organ opened by the scalpel, seen from above (``scenes/organ_cut.toml``);
- ``beam_cut.png``: the beam of thesis figure 5.10 cut in two halves (``scenes/beam_cut.toml``);
- ``sheet_crack.png``: the crack across the precut sheet (``scenes/precut_sheet.toml``).

Run::

    .venv/bin/python tools/gallery.py [--out tools/gallery] [--frames N] [--width 640]
    .venv/bin/python tools/gallery.py --scene SCENE.toml --png OUT.png   # one scene (tools/demo)

``--frames`` stops each scene early and ``--width`` sets the picture width in pixels (the
tests use small values).
"""

from __future__ import annotations

import argparse
import sys
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
        corners = mesh.linear() if getattr(mesh, "order", 1) == 2 else mesh
        triangles = corners.boundary().triangles
        original = before.linear() if getattr(before, "order", 1) == 2 else before
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
