"""Scene files (TOML) and the loop that runs them to a USD animation.

A scene names a mesh (a file or a generator), the material, damping, constraints, loads,
attachments, solver settings, duration and output. Every key is checked: an unknown key or a
value of the wrong type is a :class:`wcut.SceneError` naming the key, e.g.
``beam_sag.toml: material.youngs_modulus: expected a number, got 'soft'``.

Layout (all sections but ``[mesh]`` are optional; units SI)::

    name = "beam"                      # prim name in the USD file
    [mesh]
    path = "meshes/organ.msh"          # any format meshio reads, relative to the scene file
    # or: generator = "beam", cells = [4, 4, 20], size = [0.04, 0.04, 0.2], origin = [0, 0, 0]
    order = 2                          # quadratic elements: a tetra10 file is used as is, linear
                                       # elements get straight edge nodes (default 1: linear)
    [material]      density (kg/m^3), youngs_modulus (Pa), poisson_ratio
    [damping]       rayleigh_mass (1/s), rayleigh_stiffness (s)
    [constraints]   fixed_indices = [..], fixed_boxes = [[[x0,y0,z0],[x1,y1,z1]], ...]
    [loads]         gravity = [gx, gy, gz] (m/s^2)
    [[loads.force]] box = [[..],[..]], total = [fx, fy, fz] (N, spread evenly over the box's vertices)
    [[attachments]] point = [x, y, z] or vertex = i; target = [x, y, z]; stiffness (N/m)
    [solver]        dt (s), cg_iterations (<= 10000), cg_tolerance, rotation_iterations
    [simulation]    duration (s), fps (frames per second written)
    [output]        path, stress_colors (bool), stress_max (Pa: top of the colour scale; default:
                    the largest von Mises stress of the run), up_axis ("Z" or "Y"),
                    subdivision (quadratic elements: each curved boundary face is written as
                    4**subdivision flat triangles, 0..5, default 2)
    [cut]           a blade that cuts the object progressively (thesis chapter 5):
                    method ("paulus", "bielser", "snap", "delete"), epsilon (snapping threshold,
                    fraction of the mean edge length), frames = [f0, f1, ...] (key frames),
                    blade = [[[x,y,z],[x,y,z]], ...] (its two endpoints at each key frame, m;
                    linear in between). From f0 on, each frame cuts along the surface the
                    blade swept since the previous frame, in the current configuration.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import SceneError, WcutError
from .io import check_writable

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib


def _number(value, key):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"{key}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise SceneError(f"{key}: expected a finite number, got {value!r}")
    return float(value)


def _integer(value, key):
    if isinstance(value, bool) or not isinstance(value, int):
        raise SceneError(f"{key}: expected an integer, got {value!r}")
    return value


def _boolean(value, key):
    if not isinstance(value, bool):
        raise SceneError(f"{key}: expected true or false, got {value!r}")
    return value


def _string(value, key):
    if not isinstance(value, str):
        raise SceneError(f"{key}: expected a string, got {value!r}")
    return value


def _vec3(value, key):
    if not isinstance(value, list) or len(value) != 3:
        raise SceneError(f"{key}: expected a list of three numbers, got {value!r}")
    return [_number(v, f"{key}[{i}]") for i, v in enumerate(value)]


def _int3(value, key):
    if not isinstance(value, list) or len(value) != 3:
        raise SceneError(f"{key}: expected a list of three integers, got {value!r}")
    return [_integer(v, f"{key}[{i}]") for i, v in enumerate(value)]


def _box(value, key):
    if not isinstance(value, list) or len(value) != 2:
        raise SceneError(f"{key}: expected [[x0, y0, z0], [x1, y1, z1]], got {value!r}")
    return [_vec3(value[0], f"{key}[0]"), _vec3(value[1], f"{key}[1]")]


def _list_of(item):
    def check(value, key):
        if not isinstance(value, list):
            raise SceneError(f"{key}: expected a list, got {value!r}")
        return [item(v, f"{key}[{i}]") for i, v in enumerate(value)]
    return check


#: bounds that keep a typo from hanging a run or exhausting memory
MAX_ITERATIONS = 10000
MAX_SUBSTEPS = 10000

# section -> key -> (checker, default); a default of None means "absent unless given"
_SCHEMA = {
    "mesh": {"path": (_string, None), "generator": (_string, None), "cells": (_int3, [4, 4, 20]),
             "size": (_vec3, [0.04, 0.04, 0.2]), "origin": (_vec3, [0.0, 0.0, 0.0]),
             "tets_per_hex": (_integer, 5), "order": (_integer, 1)},
    "material": {"density": (_number, 1000.0), "youngs_modulus": (_number, 1.0e5),
                 "poisson_ratio": (_number, 0.3)},
    "damping": {"rayleigh_mass": (_number, 0.0), "rayleigh_stiffness": (_number, 0.0)},
    "constraints": {"fixed_indices": (_list_of(_integer), []), "fixed_boxes": (_list_of(_box), [])},
    "loads": {"gravity": (_vec3, [0.0, 0.0, -9.81]), "force": (None, [])},
    "solver": {"dt": (_number, 0.01), "cg_iterations": (_integer, 50), "cg_tolerance": (_number, 1.0e-5),
               "rotation_iterations": (_integer, 8)},
    "simulation": {"duration": (_number, 2.0), "fps": (_number, 30.0)},
    "output": {"path": (_string, None), "stress_colors": (_boolean, True), "stress_max": (_number, None),
               "up_axis": (_string, "Z"), "subdivision": (_integer, 2)},
}
_CUT_SCHEMA = {"method": (_string, "paulus"), "epsilon": (_number, 0.1), "frames": (_list_of(_integer), None),
               "blade": (None, None)}
_FORCE_SCHEMA = {"box": (_box, None), "total": (_vec3, None)}
_ATTACHMENT_SCHEMA = {"point": (_vec3, None), "vertex": (_integer, None), "target": (_vec3, None),
                  "stiffness": (_number, None)}


def _table(raw, schema, where):
    if not isinstance(raw, dict):
        raise SceneError(f"{where}: expected a table, got {raw!r}")
    unknown = sorted(set(raw) - set(schema))
    if unknown:
        raise SceneError(f"{where}.{unknown[0]}: unknown key (expected one of: {', '.join(sorted(schema))})")
    out = {}
    for key, (check, default) in schema.items():
        if key in raw:
            out[key] = check(raw[key], f"{where}.{key}") if check else raw[key]
        else:
            out[key] = default
    return out


@dataclass
class Scene:
    """A parsed, validated scene. ``path`` is the scene file; relative paths resolve against it."""

    path: Path
    name: str
    mesh: dict
    material: dict
    damping: dict
    constraints: dict
    loads: dict
    forces: list = field(default_factory=list)
    attachments: list = field(default_factory=list)
    solver: dict = field(default_factory=dict)
    simulation: dict = field(default_factory=dict)
    output: dict = field(default_factory=dict)
    cut: dict | None = None

    @property
    def frame_count(self) -> int:
        """Frames after the initial one: ``round(duration * fps)``."""
        return max(1, round(self.simulation["duration"] * self.simulation["fps"]))


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file. Raises :class:`SceneError` naming the file and key."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from exc
    try:
        return _parse(raw, path)
    except SceneError as exc:
        raise SceneError(f"{path.name}: {exc}") from None


def _parse(raw: dict, path: Path) -> Scene:
    top = set(_SCHEMA) | {"name", "attachments", "cut"}
    unknown = sorted(set(raw) - top)
    if unknown:
        raise SceneError(f"{unknown[0]}: unknown key (expected one of: {', '.join(sorted(top))})")
    if "mesh" not in raw:
        raise SceneError("mesh: missing section (give mesh.path or mesh.generator)")
    sections = {name: _table(raw.get(name, {}), schema, name) for name, schema in _SCHEMA.items()}
    mesh = sections["mesh"]
    if (mesh["path"] is None) == (mesh["generator"] is None):
        raise SceneError("mesh: give exactly one of mesh.path and mesh.generator")
    if mesh["generator"] not in (None, "beam"):
        raise SceneError(f"mesh.generator: unknown generator {mesh['generator']!r} (expected 'beam')")
    if mesh["order"] not in (1, 2):
        raise SceneError(f"mesh.order: expected 1 (linear) or 2 (quadratic), got {mesh['order']}")
    if not 0 <= sections["output"]["subdivision"] <= 5:
        raise SceneError(f"output.subdivision: must be in 0..5, got {sections['output']['subdivision']}")
    forces = sections["loads"].pop("force")
    if not isinstance(forces, list):
        raise SceneError("loads.force: expected an array of tables ([[loads.force]])")
    forces = [_table(f, _FORCE_SCHEMA, f"loads.force[{i}]") for i, f in enumerate(forces)]
    for i, f in enumerate(forces):
        for key in ("box", "total"):
            if f[key] is None:
                raise SceneError(f"loads.force[{i}].{key}: missing")
    attachments = raw.get("attachments", [])
    if not isinstance(attachments, list):
        raise SceneError("attachments: expected an array of tables ([[attachments]])")
    attachments = [_table(a, _ATTACHMENT_SCHEMA, f"attachments[{i}]") for i, a in enumerate(attachments)]
    for i, a in enumerate(attachments):
        if (a["point"] is None) == (a["vertex"] is None):
            raise SceneError(f"attachments[{i}]: give exactly one of point and vertex")
        for key in ("target", "stiffness"):
            if a[key] is None:
                raise SceneError(f"attachments[{i}].{key}: missing")
        if a["stiffness"] < 0:
            raise SceneError(f"attachments[{i}].stiffness: must be >= 0, got {a['stiffness']}")
    solver, sim, out = sections["solver"], sections["simulation"], sections["output"]
    for key, value in (("solver.dt", solver["dt"]), ("simulation.duration", sim["duration"]),
                       ("simulation.fps", sim["fps"]), ("material.density", sections["material"]["density"]),
                       ("material.youngs_modulus", sections["material"]["youngs_modulus"])):
        if value <= 0:
            raise SceneError(f"{key}: must be positive, got {value}")
    for key, value in sections["damping"].items():
        if value < 0:
            raise SceneError(f"damping.{key}: must be >= 0, got {value}")
    if not -1.0 < sections["material"]["poisson_ratio"] < 0.5:
        raise SceneError(f"material.poisson_ratio: must be in (-1, 0.5), got {sections['material']['poisson_ratio']}")
    for key in ("cg_iterations", "rotation_iterations"):
        if not 1 <= solver[key] <= MAX_ITERATIONS:
            raise SceneError(f"solver.{key}: must be in 1..{MAX_ITERATIONS}, got {solver[key]}")
    if solver["cg_tolerance"] < 0:
        raise SceneError(f"solver.cg_tolerance: must be >= 0, got {solver['cg_tolerance']}")
    if 1.0 / (sim["fps"] * solver["dt"]) > MAX_SUBSTEPS:
        raise SceneError(f"solver.dt: {solver['dt']} s gives more than {MAX_SUBSTEPS} steps per frame at "
                         f"simulation.fps = {sim['fps']}")
    if out["stress_max"] is not None and out["stress_max"] <= 0:
        raise SceneError(f"output.stress_max: must be positive, got {out['stress_max']}")
    if out["up_axis"] not in ("Y", "Z"):
        raise SceneError(f"output.up_axis: expected 'Y' or 'Z', got {out['up_axis']!r}")
    if "name" in raw:
        name = _string(raw["name"], "name")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise SceneError(f"name: {name!r} is not a valid object name (letters, digits, _; not a digit first)")
    else:  # from the file name, made a valid USD identifier
        name = re.sub(r"\W", "_", path.stem)
        name = name if re.match(r"[A-Za-z_]", name) else f"_{name}"
    cut = _parse_cut(raw["cut"]) if "cut" in raw else None
    return Scene(path=path, name=name, mesh=mesh, material=sections["material"], damping=sections["damping"],
                 constraints=sections["constraints"], loads=sections["loads"], forces=forces, attachments=attachments,
                 solver=solver, simulation=sim, output=out, cut=cut)


def _parse_cut(raw) -> dict:
    from .cut import METHODS

    cut = _table(raw, _CUT_SCHEMA, "cut")
    if cut["method"] not in METHODS:
        raise SceneError(f"cut.method: unknown method {cut['method']!r} (expected one of {', '.join(METHODS)})")
    if not 0.0 <= cut["epsilon"] < 0.5:
        raise SceneError(f"cut.epsilon: must be in [0, 0.5), got {cut['epsilon']}")
    frames = cut["frames"]
    if frames is None or len(frames) < 2:
        raise SceneError("cut.frames: give at least two key frames")
    if frames[0] < 0 or any(b <= a for a, b in zip(frames, frames[1:])):
        raise SceneError(f"cut.frames: expected increasing frame numbers >= 0, got {frames}")
    blade = cut["blade"]
    if not isinstance(blade, list) or len(blade) != len(frames):
        raise SceneError(f"cut.blade: expected one blade (two endpoints) per key frame ({len(frames)})")
    for i, ends in enumerate(blade):
        if not isinstance(ends, list) or len(ends) != 2:
            raise SceneError(f"cut.blade[{i}]: expected two endpoints [[x,y,z],[x,y,z]], got {ends!r}")
        for j, point in enumerate(ends):
            _vec3(point, f"cut.blade[{i}][{j}]")
    cut["blade"] = np.asarray(blade, dtype=np.float64)
    return cut


def blade_path(cut: dict) -> np.ndarray:
    """(F, 2, 3) blade endpoints (m) at every frame from the first key frame to the last."""
    keys = np.asarray(cut["frames"], dtype=np.float64)
    frames = np.arange(cut["frames"][0], cut["frames"][-1] + 1, dtype=np.float64)
    flat = cut["blade"].reshape(len(keys), 6)
    return np.stack([np.interp(frames, keys, flat[:, c]) for c in range(6)], axis=1).reshape(-1, 2, 3)


def build_mesh(scene: Scene):
    """The scene's mesh: loaded (path relative to the scene file) or generated; a
    :class:`~wcut.quadratic.QuadraticTetMesh` when ``mesh.order = 2``."""
    from .mesh import beam
    from .quadratic import load_mesh, to_quadratic

    m = scene.mesh
    if m["path"] is not None:
        return load_mesh(scene.path.parent / m["path"], m["order"])
    mesh = beam(*m["cells"], size=m["size"], origin=m["origin"], tets_per_hex=m["tets_per_hex"])
    return to_quadratic(mesh) if m["order"] == 2 else mesh


def build_model(scene: Scene, mesh=None, device=None):
    """Model, Control and external nodal forces (N, (N, 3) numpy) of a scene."""
    from .model import Attachments, Model

    where = scene.path.name
    mesh = mesh if mesh is not None else build_mesh(scene)
    c = scene.constraints

    def vertex(index: int, key: str) -> int:  # indices in a scene are the mesh file's numbering
        found = mesh.vertex_from_source(index)
        if found < 0:
            raise SceneError(f"{where}: {key}: vertex {index} is not a vertex of the tetrahedral mesh")
        return found

    fixed = [np.array([vertex(i, "constraints.fixed_indices") for i in c["fixed_indices"]], dtype=np.int64)]
    for i, box in enumerate(c["fixed_boxes"]):
        fixed.append(mesh.vertices_in_box(*box))
        if len(fixed[-1]) == 0:
            raise SceneError(f"{where}: constraints.fixed_boxes[{i}] contains no vertex")
    attached = Attachments.empty()
    for i, a in enumerate(scene.attachments):
        if a["vertex"] is not None:
            index = vertex(a["vertex"], f"attachments[{i}].vertex")
            attached = attached.concatenate(Attachments.at_vertices([index], a["stiffness"]))
        else:
            attached = attached.concatenate(Attachments.at_points(mesh, [a["point"]], a["stiffness"]))
    model = Model(mesh, **scene.material, **scene.damping, gravity=scene.loads["gravity"],
                  fixed=np.unique(np.concatenate(fixed)), attachments=attached, device=device)
    control = model.control()
    if len(scene.attachments):
        control.attachment_target.assign(np.array([a["target"] for a in scene.attachments], dtype=np.float32))
    forces = np.zeros((mesh.vertex_count, 3))
    for i, f in enumerate(scene.forces):
        ids = mesh.vertices_in_box(*f["box"])
        if len(ids) == 0:
            raise SceneError(f"{where}: loads.force[{i}].box contains no vertex")
        forces[ids] += np.asarray(f["total"]) / len(ids)
    return model, control, forces


@dataclass
class RunResult:
    """What :func:`run_scene` reports."""

    frames: int
    steps: int
    mean_step_ms: float
    nodes: int
    elements: int
    output: Path | None
    cut_events: int = 0


def run_scene(scene: Scene, output: str | os.PathLike | None = None, *, frames: int | None = None,
              progress: bool | None = None, device=None) -> RunResult:
    """Simulate a scene and write its USD animation (atomically).

    Args:
        scene: a loaded scene.
        output: the USD file (.usd, .usda or .usdc); defaults to ``[output].path`` or
            ``<scene name>.usdc`` in the current directory.
        frames: frames to simulate after the initial one (default: duration * fps).
        progress: show a progress bar; default: only when standard error is a terminal.

    Each frame advances ``1 / fps`` seconds in ``ceil(1 / (fps * dt))`` equal sub-steps.
    """
    import warp as wp

    from .solver import SolverCorotational
    from .stress import vertex_von_mises
    from .usd import UsdAnimationWriter, stress_colors

    frames = scene.frame_count if frames is None else frames
    if frames < 1:
        raise SceneError(f"frames must be at least 1, got {frames}")
    output = Path(output or scene.output["path"] or f"{scene.name}.usdc")
    fps = scene.simulation["fps"]
    writer = UsdAnimationWriter(output, fps=fps, up_axis=scene.output["up_axis"])
    check_writable(output)  # fail before the simulation, not after it
    model, control, forces = build_model(scene, device=device)
    settings = scene.solver
    solver = SolverCorotational(model, cg_iterations=settings["cg_iterations"],
                                cg_tolerance=settings["cg_tolerance"],
                                rotation_iterations=settings["rotation_iterations"])
    substeps = max(1, math.ceil(1.0 / (fps * settings["dt"]) - 1e-9))
    dt = 1.0 / (fps * substeps)
    state, next_state = model.state(), model.state()
    for each in (state, next_state):  # constant loads: the solver reads them and never clears them
        each.particle_f.assign(forces.astype(np.float32))
    subdivision = scene.output["subdivision"]
    surface = render_surface(model.mesh, subdivision)
    colored = scene.output["stress_colors"]
    # Frames are kept until the end so that every frame is coloured on one stress scale.
    points, triangles, stresses = [], [], []

    def record():
        points.append(surface.points(state.particle_q.numpy()))
        triangles.append(surface.triangles)
        if colored:  # quadratic interpolation may undershoot 0 between nodes
            stresses.append(np.maximum(surface.points(vertex_von_mises(model, state)), 0.0))

    blade = _Blade(scene.cut, model.mesh) if scene.cut else None
    cut_events = 0

    show = sys.stderr.isatty() if progress is None else progress
    bar = _progress(frames, show, scene.name)
    step_seconds, frame = 0.0, 0
    record()
    try:
        for _ in range(frames):
            start = time.perf_counter()
            for _ in range(substeps):
                solver.step(state, next_state, control, dt)
                state, next_state = next_state, state
            wp.synchronize_device(model.device)
            step_seconds += time.perf_counter() - start
            solver.check_finite()
            frame += 1
            change = blade.cut(frame, state) if blade else None
            if change is not None:
                cut_events += 1
                targets = control.attachment_target.numpy()
                model, state = model.rebuild(blade.mesh(), change, state)
                next_state, control = model.state(), model.control()
                next_state.particle_f.assign(state.particle_f)
                control.attachment_target.assign(targets)
                solver = SolverCorotational(model, cg_iterations=settings["cg_iterations"],
                                            cg_tolerance=settings["cg_tolerance"],
                                            rotation_iterations=settings["rotation_iterations"])
                surface = render_surface(model.mesh, subdivision)
            record()
            bar.update(1)
    finally:
        bar.close()
    stress_max = scene.output["stress_max"] or (max(float(v.max()) for v in stresses) if colored else 0.0)
    with writer:
        for frame, frame_points in enumerate(points):
            colors = stress_colors(stresses[frame], vmin=0.0, vmax=max(stress_max, 1e-30)) if colored else None
            writer.write_frame(scene.name, frame, frame_points, triangles[frame], colors)
    return RunResult(frames=frames, steps=frames * substeps, mean_step_ms=1e3 * step_seconds / (frames * substeps),
                     nodes=model.particle_count, elements=model.tet_count, output=output, cut_events=cut_events)


def render_surface(mesh, subdivision: int = 2):
    """What is written of a mesh's boundary: its triangles (linear mesh) or its curved faces
    tessellated ``subdivision`` times (quadratic mesh, shell); a
    :class:`~wcut.quadratic.SurfaceTessellation`."""
    from .mesh import ShellMesh
    from .quadratic import SurfaceTessellation

    if getattr(mesh, "order", 1) == 2 or isinstance(mesh, ShellMesh):
        return mesh.surface_tessellation(subdivision)
    return SurfaceTessellation.of_linear(mesh)


class _Blade:
    """The scene's blade: cuts the object where it swept since the last frame.

    The blade is a segment in the world; the material it cuts between two frames is what it
    met on the way, which a moving body keeps changing. Each frame, points along the blade are
    mapped from the current configuration to the rest configuration
    (:meth:`~wcut.topology.TetTopology.rest_points`, thesis 3.2), and the cut is the strip
    between the blade mapped last frame and the blade mapped now: consecutive strips share
    their edges in the material, so the wound has no gaps however the body moves. The cuts
    are progressive (see :meth:`wcut.cut.Cutter.cut`): an element opens once the blade has
    passed through it."""

    def __init__(self, cut: dict, mesh):
        from .cut import Cutter, SweptBlade
        from .cut.quadratic import QuadraticCutter
        from .topology import TetTopology

        self.first = cut["frames"][0]
        self.sweep = SweptBlade(blade_path(cut))
        if getattr(mesh, "order", 1) == 2:  # the corners are cut, the nodes placed after
            self.quadratic, self._linear = QuadraticCutter(mesh, method=cut["method"], epsilon=cut["epsilon"]), None
        else:
            self.quadratic, self._linear = None, Cutter(TetTopology(mesh), method=cut["method"],
                                                        epsilon=cut["epsilon"])
        #: increments a quadratic cut refused (an element would fold): they are cut again with the next
        self.refused = 0
        length = float(np.linalg.norm(self.sweep.blade[:, 1] - self.sweep.blade[:, 0], axis=1).max())
        # a sample every half edge: the mapped blade follows the body's bending
        self.sample_count = int(np.clip(np.ceil(2.0 * length / self.cutter.mean_edge_length), 2, 64)) + 1
        self._mapped = None  # the blade of the last frame, in the rest configuration

    def cut(self, frame: int, state):
        """The TopologyChange of this frame's cut, or None when nothing changed."""
        from .cut.surface import strip

        k = frame - self.first
        if not 0 <= k < self.sweep.frame_count:
            return None
        if self.quadratic is not None:
            self.quadratic.set_state(state.particle_q.numpy(), state.particle_qd.numpy())
        else:
            n = self.topology.vertex_count
            self.topology.positions[:] = state.particle_q.numpy()[:n]
            self.topology.velocities[:] = state.particle_qd.numpy()[:n]
        before = self._mapped
        self._mapped = self.topology.rest_points(self.sweep.samples(k, self.sample_count))
        if before is None:
            return None
        increment = strip(before, self._mapped)
        if increment is None:
            return None
        if self.quadratic is None:
            change = self.cutter.cut(increment, progressive=True, rest=True).change
        else:
            from .cut import CutError

            try:
                change = self.quadratic.cut(increment, progressive=True, rest=True).change
            except CutError:
                self.refused += 1
                return None
        return None if change.is_empty else change

    @property
    def cutter(self):
        """The corner mesh's :class:`~wcut.cut.Cutter`."""
        return self.quadratic.cutter if self.quadratic is not None else self._linear

    @property
    def topology(self):
        """The corner mesh being cut."""
        return self.cutter.topology

    def mesh(self):
        """The mesh after the last cut."""
        return self.quadratic.mesh if self.quadratic is not None else self.topology.to_mesh()


class _NoBar:
    def update(self, n):
        pass

    def close(self):
        pass


def _progress(total: int, show: bool, label: str):
    if not show:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit="frame", file=sys.stderr, leave=False)


__all__ = ["Scene", "RunResult", "load_scene", "build_mesh", "build_model", "run_scene", "WcutError"]
