"""Synthetic captures with ground truth: ``wcut synth SCENE.toml -o DIR``.

No surgical video ships with wcut, so the "real" object is simulated by wcut itself: a scene
(a finer mesh than the model the pipeline will register, stretched by moving attachments and
cut by a blade whose path continues as a tear) is rendered each frame through a pinhole
camera by Warp ray casting, with a texture attached to the material so that features can be
tracked. A synthetic scene is an ordinary scene file (:mod:`wcut.scene`) with two more
sections::

    [camera]        eye, target (m), up, width, height (pixels), fov_y_deg
    [synth]         model = { generator = "beam", cells = [..], size = [..], origin = [..] } or
                    { path = "meshes/x.vtu" }: the registered model (coarser than the truth)
                    texture_scale (m, default 4e-3), texture_seed (default 1),
                    roi_erosion (pixels the region of interest is shrunk from the object's
                    first-frame outline, default 3)
    [[synth.internal]]  name, points = [[x, y, z], ...] (a polyline, m), radius (m),
                    segments (around, default 10): a capped tube inside the object
    [synth.params]  the capture's params.toml, passed through (see :mod:`wcut.ar.params`)

The blade's key frames (``[cut]``) give the true cut: a precut object is cut in the first
frames while at rest; a tear is the blade's path going on faster. The capture directory::

    frames/0000.png ...      the video (BGR PNG)
    camera.json  mask.png    intrinsics and pose; the region of interest (white)
    model.vtu                the model registered to the first frame
    internal/NAME.obj        internal structures (rest = first frame)
    params.toml              pipeline settings
    truth/masks/0000.png     the object's pixels in each frame
    truth/frames/0000.npz    surface_points, surface_triangles, and per structure
                             NAME_points, NAME_triangles (m, the truth's current configuration)
    truth/cut.obj            the true cut surface (m, rest configuration)
    truth/truth.json         frames, fps, the frames in which the blade cut
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ..cut.surface import TriangleSurface, joined
from ..errors import CaptureError, SceneError
from ..scene import (Scene, Simulation, _integer, _parse, _parse_mesh, _progress, _table, build_mesh, render_surface,
                     tomllib)
from .camera import Camera
from .internal import InternalStructure
from .render import Renderer, Texture

_CAMERA_SCHEMA = {"eye": (None, None), "target": (None, None), "up": (None, [0.0, 0.0, 1.0]),
                  "width": (None, 480), "height": (None, 360), "fov_y_deg": (None, 45.0)}
_SYNTH_SCHEMA = {"model": (None, None), "texture_scale": (None, 4.0e-3), "texture_seed": (None, 1),
                 "roi_erosion": (None, 3), "internal": (None, []), "params": (None, {})}
_TUBE_SCHEMA = {"name": (None, None), "points": (None, None), "radius": (None, None), "segments": (None, 10)}


@dataclasses.dataclass
class SynthScene:
    """A parsed synthetic scene: the simulated scene, the camera and the [synth] table."""

    scene: Scene
    camera: Camera
    synth: dict


@dataclasses.dataclass
class SynthResult:
    """What :func:`synthesize` reports."""

    directory: Path
    frames: int
    cut_frames: list
    truth_elements: int
    model_elements: int


def load_synth_scene(path) -> SynthScene:
    """Read a synthetic scene (a scene with [camera] and [synth]); errors name file and key."""
    from ..scene import _number, _string, _vec3

    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SceneError(f"{path}: cannot read: {exc}") from None
    try:
        for key in ("camera", "synth"):
            if key not in raw:
                raise SceneError(f"{key}: missing section (a synthetic capture needs [camera] and [synth])")
        camera_raw, synth_raw = raw.pop("camera"), raw.pop("synth")
        scene = _parse(raw, path)
        c = _table(camera_raw, _CAMERA_SCHEMA, "camera")
        for key in ("eye", "target"):
            if c[key] is None:
                raise SceneError(f"camera.{key}: missing")
        camera = Camera.look_at(_vec3(c["eye"], "camera.eye"), _vec3(c["target"], "camera.target"),
                                up=_vec3(c["up"], "camera.up"), width=_integer(c["width"], "camera.width"),
                                height=_integer(c["height"], "camera.height"),
                                fov_y_deg=_number(c["fov_y_deg"], "camera.fov_y_deg"))
        s = _table(synth_raw, _SYNTH_SCHEMA, "synth")
        if s["model"] is None:
            raise SceneError("synth.model: missing (the registered model's mesh: path or generator)")
        from ..scene import _SCHEMA

        s["model"] = _parse_mesh(_table(s["model"], _SCHEMA["mesh"], "synth.model"), s["model"])
        s["texture_scale"] = _number(s["texture_scale"], "synth.texture_scale")
        s["texture_seed"] = _integer(s["texture_seed"], "synth.texture_seed")
        s["roi_erosion"] = _integer(s["roi_erosion"], "synth.roi_erosion")
        if not isinstance(s["params"], dict):
            raise SceneError("synth.params: expected a table")
        tubes = []
        for i, t in enumerate(s["internal"] if isinstance(s["internal"], list) else [None]):
            where = f"synth.internal[{i}]"
            t = _table(t, _TUBE_SCHEMA, where)
            for key in ("name", "points", "radius"):
                if t[key] is None:
                    raise SceneError(f"{where}.{key}: missing")
            points = t["points"]
            if not isinstance(points, list) or len(points) < 2:
                raise SceneError(f"{where}.points: expected at least two points [[x, y, z], ...]")
            tubes.append({"name": _string(t["name"], f"{where}.name"),
                          "points": [_vec3(p, f"{where}.points[{j}]") for j, p in enumerate(points)],
                          "radius": _number(t["radius"], f"{where}.radius"),
                          "segments": _integer(t["segments"], f"{where}.segments")})
        s["internal"] = tubes
    except (SceneError, CaptureError) as exc:
        raise SceneError(f"{path.name}: {exc}") from None
    return SynthScene(scene, camera, s)


def tube(points, radius: float, segments: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube of ``radius`` (m) around the polyline ``points`` (n, 3) (m), capped at
    both ends: (vertices, triangles), outward oriented."""
    p = np.asarray(points, dtype=np.float64)
    tangent = np.gradient(p, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    helper = np.array([0.0, 0.0, 1.0]) if abs(tangent[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    rings = []
    for point, t in zip(p, tangent):
        u = np.cross(t, helper)
        u /= np.linalg.norm(u)
        w = np.cross(t, u)
        angle = 2.0 * np.pi * np.arange(segments) / segments
        rings.append(point + radius * (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * w))
    n = len(p)
    vertices = np.concatenate(rings + [p[:1], p[-1:]])
    triangles = []
    for i in range(n - 1):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            triangles += [(a, b, b + segments), (a, b + segments, a + segments)]
    first, last = n * segments, n * segments + 1
    for j in range(segments):
        triangles.append((first, (j + 1) % segments, j))
        triangles.append((last, (n - 1) * segments + j, (n - 1) * segments + (j + 1) % segments))
    return vertices, np.array(triangles, dtype=np.int64)


def toml_text(table: dict) -> str:
    """A nested table of numbers, strings, booleans and lists as TOML text."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise SceneError(f"synth.params: cannot write {v!r} to TOML")

    lines, tables = [], []
    for key, v in table.items():
        (tables if isinstance(v, dict) else lines).append((key, v))
    out = [f"{k} = {value(v)}" for k, v in lines]
    for key, sub in tables:
        out.append(f"\n[{key}]")
        out += [f"{k} = {value(v)}" for k, v in sub.items()]
    return "\n".join(out) + "\n"


def synthesize(path, directory, *, frames: int | None = None, progress: bool | None = None,
               texture_seed: int | None = None) -> SynthResult:
    """Simulate and render a synthetic scene into the capture ``directory`` (replaced
    atomically: the capture is written beside it and renamed when complete).

    ``texture_seed`` replaces the scene's ``synth.texture_seed``: another rendering of the
    same truth (object, cut, camera), to test that detection settings carry over."""
    import sys

    ss = load_synth_scene(path)
    scene, camera, synth = ss.scene, ss.camera, ss.synth
    if texture_seed is not None:
        synth = {**synth, "texture_seed": _integer(texture_seed, "texture_seed")}
    frames = scene.frame_count if frames is None else int(frames)
    if frames < 1:
        raise SceneError(f"frames must be at least 1, got {frames}")
    directory = Path(directory)
    _check_replaceable(directory)
    model_mesh = build_mesh(dataclasses.replace(scene, mesh=synth["model"]))
    if getattr(model_mesh, "order", 1) != 1 or not hasattr(model_mesh, "tets"):
        raise SceneError(f"{scene.path.name}: synth.model: the registered model must be a linear tetrahedral mesh")
    sim = Simulation(scene)
    if sim.model.tri_count or sim.model.tet_order != 1:
        raise SceneError(f"{scene.path.name}: mesh: the simulated object must be a linear tetrahedral mesh")
    truth_mesh = sim.model.mesh
    tubes = [tube(t["points"], t["radius"], t["segments"]) for t in synth["internal"]]
    truths = [InternalStructure.embedded(t["name"], v, f, truth_mesh.vertices, truth_mesh.tets,
                                         what=f"synth.internal {t['name']}") for t, (v, f) in zip(synth["internal"], tubes)]
    renderer, texture = Renderer(camera), Texture(seed=synth["texture_seed"], scale=synth["texture_scale"])

    try:
        directory.parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f".{directory.name}.", dir=directory.parent))
    except OSError as exc:
        raise CaptureError(f"{directory}: cannot write here: {exc.strerror or exc}") from None
    try:
        for sub in ("frames", "internal", "truth/masks", "truth/frames"):
            (work / sub).mkdir(parents=True)
        camera.to_json(work / "camera.json")
        model_mesh.save(work / "model.vtu")
        for t, (v, f) in zip(synth["internal"], tubes):
            TriangleSurface(v, f).save(work / "internal" / f"{t['name']}.obj")
        params = {k: v for k, v in synth["params"].items()}
        params.setdefault("video", {})["fps"] = scene.simulation["fps"]
        (work / "params.toml").write_text(toml_text(params), encoding="utf-8")

        mesh, surface = truth_mesh, render_surface(truth_mesh)
        cut_frames, swept = [], []
        show = sys.stderr.isatty() if progress is None else progress
        bar = _progress(frames + 1, show, f"synth {scene.name}")
        try:
            for frame in range(frames + 1):
                if frame:
                    sim.advance()
                    for mesh, change in sim.changes:
                        for t in truths:
                            t.after(change, mesh.vertices, mesh.tets)
                    if sim.changes:
                        mesh, surface = sim.model.mesh, render_surface(sim.model.mesh)
                    blade = sim.blade
                    if blade is not None and blade.last_increment is not None:
                        swept.append(blade.last_increment)
                        for t in truths:
                            t.cut(blade.last_increment)
                    if sim.changes:
                        cut_frames.append(frame)
                x = sim.state.particle_q.numpy().astype(np.float64)
                points, rest = surface.points(x), surface.points(mesh.vertices)
                image, mask = renderer.render(points, surface.triangles, rest, texture)
                name = f"{frame:04d}.png"
                _imwrite(work / "frames" / name, image)
                _imwrite(work / "truth" / "masks" / name, mask.astype(np.uint8) * 255)
                arrays = {"surface_points": points, "surface_triangles": surface.triangles}
                for t in truths:
                    arrays[f"{t.name}_points"] = t.positions(x, mesh.tets)
                    arrays[f"{t.name}_triangles"] = t.triangles
                np.savez_compressed(work / "truth" / "frames" / f"{frame:04d}.npz", **arrays)
                if frame == 0:
                    roi = mask.astype(np.uint8)
                    if synth["roi_erosion"] > 0:
                        size = 2 * synth["roi_erosion"] + 1
                        roi = cv2.erode(roi, np.ones((size, size), np.uint8))
                    _imwrite(work / "mask.png", roi * 255)
                bar.update(1)
        finally:
            bar.close()
        if swept:
            joined(swept).save(work / "truth" / "cut.obj")
        truth = {"frames": frames + 1, "fps": scene.simulation["fps"], "cut_frames": cut_frames,
                 "scene": scene.name, "truth_elements": int(sim.model.tet_count),
                 "internal": [t.name for t in truths]}
        (work / "truth" / "truth.json").write_text(json.dumps(truth, indent=1), encoding="utf-8")
        if directory.exists():
            shutil.rmtree(directory)
        os.replace(work, directory)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return SynthResult(directory, frames + 1, cut_frames, int(sim.model.tet_count), int(model_mesh.tet_count))


#: What a capture directory holds: a non-empty directory without them is the user's, and is
#: not replaced.
CAPTURE_FILES = ("camera.json", "truth")


def _check_replaceable(directory: Path) -> None:
    """Refuse, before any work, an output that is a file or a non-empty directory that is not
    a capture (replacing it would delete the user's files)."""
    if directory.exists() and not directory.is_dir():
        raise CaptureError(f"{directory}: is a file, not a capture directory")
    if directory.is_dir() and any(directory.iterdir()) \
            and not all((directory / name).exists() for name in CAPTURE_FILES):
        raise CaptureError(f"{directory}: a directory with other files than a capture; give a new or empty "
                           "directory (wcut synth replaces the one it writes)")


def _imwrite(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise CaptureError(f"{path}: cannot write the image")
