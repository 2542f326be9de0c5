"""Scene files (TOML) and the loop that runs them to a USD animation.

A scene names a mesh (a file or a generator), the material, damping, constraints, loads,
attachments, solver settings, duration and output. Every key is checked: an unknown key or a
value of the wrong type is a :class:`wcut.SceneError` naming the key, e.g.
``beam_sag.toml: material.youngs_modulus: expected a number, got 'soft'``.

Layout (all sections but ``[mesh]`` are optional; units SI)::

    name = "beam"                      # prim name in the USD file
    [mesh]
    path = "meshes/organ.msh"          # any format meshio reads, relative to the scene file; a
                                       # file with tetra/tetra10 cells is a solid, one with only
                                       # triangle/triangle6 cells a thin shell (ShellMesh.load)
    # or: generator = "beam", cells = [4, 4, 20], size = [0.04, 0.04, 0.2] (m), origin = [0, 0, 0] (m),
    #     tets_per_hex = 5 (5 or 6)
    order = 2                          # solids: quadratic elements: a tetra10 file is used as is,
                                       # linear elements get straight edge nodes (default 1: linear);
                                       # shells are always quadratic triangles: 2 or absent
    # thin shells (6-node triangles, flat in the plane z = origin z, normal +z):
    # generator = "rectangle_sheet", cells = [nx, ny] (default [8, 8]), size = [w, h] (m, default
    #     [0.2, 0.2]), origin = [x, y, z] (m, the lowest corner)
    # generator = "l_shape_sheet": a square of cells = [n, n] cells (n even, default [8, 8]) and
    #     size = [s, s] (m) without its top-right quadrant; the re-entrant corner is at the centre
    # generator = "precut_sheet": as rectangle_sheet (ny even) with a slit from the middle of the
    #     left side along +x, notch_length (m, default w / 2) rounded to whole cells
    # pattern = "alternate" or "right"     sheets: cell diagonals criss-cross or all lower left to
    #                                      upper right (default "alternate")
    thickness = 1e-3                   # shells only (m, default 1e-3)
    [material]      density (kg/m^3), youngs_modulus (Pa), poisson_ratio
    [damping]       rayleigh_mass (1/s), rayleigh_stiffness (s)
    [constraints]   fixed_indices = [..] (the mesh file's numbering), fixed_boxes = [[[x0,y0,z0],[x1,y1,z1]], ...]
    [loads]         gravity = [gx, gy, gz] (m/s^2)
    [[loads.force]] box = [[..],[..]], total = [fx, fy, fz] (N, spread evenly over the box's vertices)
    [[attachments]] point = [x, y, z] or vertex = i; target = [x, y, z]; stiffness (N/m). A point is
                    held by the element containing it (a shell: the nearest triangle, point
                    projected onto it). box = [[..],[..]] holds every vertex in it at its rest
                    position. The targets move with velocity = [vx, vy, vz] (m/s) or along
                    keyframes = [[t, dx, dy, dz], ...] (s, m: offsets from the start, linear in
                    between, held after the last)
    [solver]        dt (s; default 1 / fps: one step per frame), preconditioner ("cholesky" or
                    "jacobi"; default: the solver's), cg_tolerance and cg_iterations (the solver's
                    defaults: a relative residual and a safety cap), rotation_iterations,
                    rotation_stiffness (bool, default true: the tangent's rotation term in the
                    system matrix, see wcut.solver; false: the thesis's R K R^T), cpu_threads
                    (1..8: threads of the element kernels on the CPU; default: by model size)
    [simulation]    duration (s), fps (frames per second written)
    [output]        path, stress_colors (bool), stress_max (Pa: top of the colour scale; default:
                    the largest von Mises stress of the run), up_axis ("Z" or "Y"),
                    subdivision (quadratic elements: each curved boundary face is written as
                    4**subdivision flat triangles, 0..5, default 2)
    [cut]           a blade that cuts the object progressively (thesis chapter 5):
                    method ("paulus", "bielser", "snap", "delete"), epsilon (snapping threshold,
                    fraction of the mean edge length), improve (local mesh improvement after
                    each frame's cut; default: on, but for curved quadratic elements),
                    frames = [f0, f1, ...] (key frames), blade = [[[x,y,z],[x,y,z]], ...]
                    (its two endpoints at each key frame, m; linear in between). From f0 on,
                    each frame cuts along the surface the blade swept since the previous
                    frame, in the current configuration. Solids only: a shell is not cut by a
                    blade.
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

from .blade import Blade, sample_count
from .errors import SceneError, WcutError
from .io import check_writable
from .mesh import SHEET_PATTERNS
from .model import MAX_GRAVITY
from .rebuild import apply_change

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


def _thread_count(value, key):
    from .split_launch import MAX_THREADS

    if not 1 <= _integer(value, key) <= MAX_THREADS:
        raise SceneError(f"{key}: expected 1 to {MAX_THREADS} threads, got {value!r}")
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
#: the longest time step (s) a scene may take (its dt, or 1 / fps without one)
MAX_STEP = 1.0
#: the most frames a scene may ask for (duration * fps): a day at 30 fps is 2.6 million
MAX_FRAMES = 10_000_000
#: the most cells a mesh generator may make (five or six elements each)
MAX_CELLS = 10_000_000

# section -> key -> (checker, default); a default of None means "absent unless given"
_SCHEMA = {
    # cells, size and order are checked by _parse_mesh: their rules depend on the generator
    "mesh": {"path": (_string, None), "generator": (_string, None), "cells": (None, None), "size": (None, None),
             "origin": (_vec3, [0.0, 0.0, 0.0]), "tets_per_hex": (_integer, 5), "order": (_integer, None),
             "pattern": (_string, None), "notch_length": (_number, None), "thickness": (_number, None)},
    "material": {"density": (_number, 1000.0), "youngs_modulus": (_number, 1.0e5),
                 "poisson_ratio": (_number, 0.3)},
    "damping": {"rayleigh_mass": (_number, 0.0), "rayleigh_stiffness": (_number, 0.0)},
    "constraints": {"fixed_indices": (_list_of(_integer), []), "fixed_boxes": (_list_of(_box), [])},
    "loads": {"gravity": (_vec3, [0.0, 0.0, -9.81]), "force": (None, [])},
    "solver": {"dt": (_number, None), "cg_iterations": (_integer, None), "cg_tolerance": (_number, None),
               "preconditioner": (_string, None),
               "rotation_iterations": (_integer, 8), "rotation_stiffness": (_boolean, True),
               "cpu_threads": (_thread_count, None)},
    "simulation": {"duration": (_number, 2.0), "fps": (_number, 30.0)},
    "output": {"path": (_string, None), "stress_colors": (_boolean, True), "stress_max": (_number, None),
               "up_axis": (_string, "Z"), "subdivision": (_integer, 2)},
}
#: the generators of thin shells (wcut.mesh); a sheet's defaults are cells = [8, 8], size = [0.2, 0.2] m
SHEET_GENERATORS = ("rectangle_sheet", "l_shape_sheet", "precut_sheet")
GENERATORS = ("beam",) + SHEET_GENERATORS
#: default thickness (m) of a shell
DEFAULT_THICKNESS = 1.0e-3
_SHEET_CELLS = [8, 8]
_SHEET_SIZE = [0.2, 0.2]

_CUT_SCHEMA = {"method": (_string, "paulus"), "epsilon": (_number, 0.1), "improve": (_boolean, None),
               "frames": (_list_of(_integer), None), "blade": (None, None)}
_FORCE_SCHEMA = {"box": (_box, None), "total": (_vec3, None)}
_ATTACHMENT_SCHEMA = {"point": (_vec3, None), "vertex": (_integer, None), "box": (_box, None),
                      "target": (_vec3, None), "stiffness": (_number, None), "velocity": (_vec3, [0.0, 0.0, 0.0]),
                      "keyframes": (None, None)}
_FRACTURE_SCHEMA = {"strength": (_number, None), "variant": (_string, "none"), "max_cracks_per_step": (_integer, 1),
                    "smoothing": (_string, "max"), "direction_smoothing": (_string, "weighted"),
                    "min_quality": (_number, None)}


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
    fracture: dict | None = None

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
    top = set(_SCHEMA) | {"name", "attachments", "cut", "fracture"}
    unknown = sorted(set(raw) - top)
    if unknown:
        raise SceneError(f"{unknown[0]}: unknown key (expected one of: {', '.join(sorted(top))})")
    if "mesh" not in raw:
        raise SceneError("mesh: missing section (give mesh.path or mesh.generator)")
    sections = {name: _table(raw.get(name, {}), schema, name) for name, schema in _SCHEMA.items()}
    mesh = _parse_mesh(sections["mesh"], raw["mesh"])
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
        if sum(a[key] is not None for key in ("point", "vertex", "box")) != 1:
            raise SceneError(f"attachments[{i}]: give exactly one of point, vertex and box")
        if a["box"] is not None and a["target"] is not None:
            raise SceneError(f"attachments[{i}].target: a box holds each vertex at its rest position (move it "
                             f"with velocity)")
        for key in ("target", "stiffness"):
            if a[key] is None and not (key == "target" and a["box"] is not None):
                raise SceneError(f"attachments[{i}].{key}: missing")
        if a["stiffness"] < 0:
            raise SceneError(f"attachments[{i}].stiffness: must be >= 0, got {a['stiffness']}")
        if a["keyframes"] is not None:
            a["keyframes"] = _keyframes(a["keyframes"], f"attachments[{i}].keyframes")
            if any(a["velocity"]):
                raise SceneError(f"attachments[{i}].keyframes: give keyframes or velocity, not both")
    solver, sim, out = sections["solver"], sections["simulation"], sections["output"]
    for key, value in (("solver.dt", 1.0 if solver["dt"] is None else solver["dt"]),
                       ("simulation.duration", sim["duration"]),
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
        if solver[key] is not None and not 1 <= solver[key] <= MAX_ITERATIONS:
            raise SceneError(f"solver.{key}: must be in 1..{MAX_ITERATIONS}, got {solver[key]}")
    if solver["cg_tolerance"] is not None and solver["cg_tolerance"] < 0:
        raise SceneError(f"solver.cg_tolerance: must be >= 0, got {solver['cg_tolerance']}")
    if solver["preconditioner"] not in (None, "cholesky", "jacobi"):
        raise SceneError(f"solver.preconditioner: expected 'cholesky' or 'jacobi', got {solver['preconditioner']!r}")
    if (solver["dt"] or 1.0 / sim["fps"]) > MAX_STEP:
        raise SceneError(f"solver.dt: a step of {solver['dt'] or 1.0 / sim['fps']:.3g} s "
                         f"({'solver.dt' if solver['dt'] else '1 / simulation.fps'}) is longer than {MAX_STEP} s")
    if solver["dt"] is not None and 1.0 / (sim["fps"] * solver["dt"]) > MAX_SUBSTEPS:
        raise SceneError(f"solver.dt: {solver['dt']} s gives more than {MAX_SUBSTEPS} steps per frame at "
                         f"simulation.fps = {sim['fps']}")
    if sim["duration"] * sim["fps"] > MAX_FRAMES:
        raise SceneError(f"simulation: duration {sim['duration']:g} s at fps {sim['fps']:g} is "
                         f"{sim['duration'] * sim['fps']:.3g} frames; at most {MAX_FRAMES}")
    gravity = np.asarray(sections["loads"]["gravity"], dtype=np.float64)
    if not np.abs(gravity).max() <= MAX_GRAVITY:  # (the model checks it too: here before any work)
        raise SceneError(f"loads.gravity: {gravity.tolist()} m/s^2 is beyond any load a simulation takes "
                         f"(at most {MAX_GRAVITY:g} m/s^2 along each axis)")
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
    fracture = _parse_fracture(raw["fracture"]) if "fracture" in raw else None
    return Scene(path=path, name=name, mesh=mesh, material=sections["material"], damping=sections["damping"],
                 constraints=sections["constraints"], loads=sections["loads"], forces=forces, attachments=attachments,
                 solver=solver, simulation=sim, output=out, cut=cut, fracture=fracture)


def _keyframes(value, key) -> np.ndarray:
    """(K, 4) rows ``[t, dx, dy, dz]``: times (s, increasing from >= 0) and target offsets (m)."""
    if not isinstance(value, list) or len(value) < 2:
        raise SceneError(f"{key}: expected at least two rows [t, dx, dy, dz] (s, m)")
    rows = []
    for j, row in enumerate(value):
        if not isinstance(row, list) or len(row) != 4:
            raise SceneError(f"{key}[{j}]: expected [t, dx, dy, dz], got {row!r}")
        rows.append([_number(v, f"{key}[{j}][{c}]") for c, v in enumerate(row)])
    rows = np.asarray(rows)
    if rows[0, 0] < 0 or np.any(np.diff(rows[:, 0]) <= 0):
        raise SceneError(f"{key}: times must increase from >= 0 s, got {rows[:, 0].tolist()}")
    return rows


def _parse_mesh(mesh: dict, raw: dict) -> dict:
    """The [mesh] table with the rules that depend on the generator checked and its defaults
    filled in. ``order`` stays None for a file without mesh.order (1 for tetrahedra, 2 for a
    shell: the file decides); ``thickness`` is None where the mesh is known to be a solid."""
    if (mesh["path"] is None) == (mesh["generator"] is None):
        raise SceneError("mesh: give exactly one of mesh.path and mesh.generator")
    generator = mesh["generator"]
    if generator is not None and generator not in GENERATORS:
        raise SceneError(f"mesh.generator: unknown generator {generator!r} (expected one of "
                         f"{', '.join(repr(g) for g in GENERATORS)})")
    sheet = generator in SHEET_GENERATORS

    def only(key: str, allowed: bool, where: str) -> None:
        if key in raw and not allowed:
            raise SceneError(f"mesh.{key}: only for {where}")

    only("tets_per_hex", not sheet, "the beam generator and tetrahedral files")
    only("pattern", sheet, f"the sheet generators ({', '.join(SHEET_GENERATORS)})")
    only("notch_length", generator == "precut_sheet", "generator = 'precut_sheet'")
    only("thickness", generator != "beam", "shells (sheet generators and triangle files), not the beam")
    if mesh["order"] is not None and mesh["order"] not in (1, 2):
        raise SceneError(f"mesh.order: expected 1 (linear) or 2 (quadratic), got {mesh['order']}")
    if mesh["thickness"] is not None and mesh["thickness"] <= 0:
        raise SceneError(f"mesh.thickness: must be positive, got {mesh['thickness']}")
    if not sheet:  # the beam, or a file of either kind: the solid's rules, as they always were
        mesh["cells"] = _int3(raw["cells"], "mesh.cells") if "cells" in raw else [4, 4, 20]
        if math.prod(mesh["cells"]) > MAX_CELLS:
            raise SceneError(f"mesh.cells: {mesh['cells']} is {math.prod(mesh['cells']):.3g} cells; at most "
                             f"{MAX_CELLS:g} (some {6 * MAX_CELLS:g} elements)")
        mesh["size"] = _vec3(raw["size"], "mesh.size") if "size" in raw else [0.04, 0.04, 0.2]
        if generator == "beam" and mesh["order"] is None:
            mesh["order"] = 1
        return mesh
    if mesh["order"] not in (None, 2):
        raise SceneError(f"mesh.order: a shell is made of quadratic triangles: expected 2 or no mesh.order, "
                         f"got {mesh['order']}")
    mesh["order"] = 2
    mesh["thickness"] = DEFAULT_THICKNESS if mesh["thickness"] is None else mesh["thickness"]
    mesh["pattern"] = "alternate" if mesh["pattern"] is None else mesh["pattern"]
    if mesh["pattern"] not in SHEET_PATTERNS:
        raise SceneError(f"mesh.pattern: expected one of {', '.join(repr(p) for p in SHEET_PATTERNS)}, "
                         f"got {mesh['pattern']!r}")
    cells = raw.get("cells", list(_SHEET_CELLS))
    if not isinstance(cells, list) or len(cells) != 2:
        raise SceneError(f"mesh.cells: expected a list of two integers [nx, ny] for {generator}, got {cells!r}")
    cells = [_integer(v, f"mesh.cells[{i}]") for i, v in enumerate(cells)]
    size = raw.get("size", list(_SHEET_SIZE))
    if not isinstance(size, list) or len(size) != 2:
        raise SceneError(f"mesh.size: expected a list of two lengths [w, h] (m) for {generator}, got {size!r}")
    size = [_number(v, f"mesh.size[{i}]") for i, v in enumerate(size)]
    if min(cells) < 1:
        raise SceneError(f"mesh.cells: expected at least one cell along x and y, got {cells}")
    if math.prod(cells) > MAX_CELLS:
        raise SceneError(f"mesh.cells: {cells} is {math.prod(cells):.3g} cells; at most {MAX_CELLS:g}")
    if min(size) <= 0:
        raise SceneError(f"mesh.size: must be positive, got {size}")
    if generator == "l_shape_sheet" and (cells[0] != cells[1] or cells[0] % 2):
        raise SceneError(f"mesh.cells: the L-shape is a square of [n, n] cells without a quadrant: expected two "
                         f"equal even integers, got {cells}")
    if generator == "l_shape_sheet" and size[0] != size[1]:
        raise SceneError(f"mesh.size: the L-shape is a square: expected two equal lengths [s, s] (m), got {size}")
    if generator == "precut_sheet":
        if cells[1] % 2:
            raise SceneError(f"mesh.cells: precut_sheet needs an even ny (the slit is the grid line y = h/2), "
                             f"got {cells}")
        notch = size[0] / 2 if mesh["notch_length"] is None else mesh["notch_length"]
        whole = math.floor(notch / (size[0] / cells[0]) + 0.5)  # as wcut.mesh.precut_sheet rounds it
        if not (0 < notch < size[0] and 1 <= whole <= cells[0] - 1):
            raise SceneError(f"mesh.notch_length: {notch:g} m rounds to {whole} cells of {size[0] / cells[0]:g} m; "
                             f"the slit must be 1..{cells[0] - 1} cells long (inside the sheet)")
        mesh["notch_length"] = notch
    mesh["cells"], mesh["size"] = cells, size
    return mesh


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


def _parse_fracture(raw) -> dict:
    from .fracture import VARIANTS

    fracture = _table(raw, _FRACTURE_SCHEMA, "fracture")
    if fracture["strength"] is None:
        raise SceneError("fracture.strength: missing (the ultimate tensile strength, Pa)")
    if fracture["strength"] <= 0:
        raise SceneError(f"fracture.strength: must be positive, got {fracture['strength']}")
    if fracture["variant"] not in VARIANTS:
        raise SceneError(f"fracture.variant: unknown variant {fracture['variant']!r} (expected one of "
                         f"{', '.join(VARIANTS)})")
    if not 1 <= fracture["max_cracks_per_step"] <= MAX_ITERATIONS:
        raise SceneError(f"fracture.max_cracks_per_step: must be in 1..{MAX_ITERATIONS}, got "
                         f"{fracture['max_cracks_per_step']}")
    for key in ("smoothing", "direction_smoothing"):
        if fracture[key] not in ("max", "weighted"):
            raise SceneError(f"fracture.{key}: expected 'max' or 'weighted', got {fracture[key]!r}")
    if fracture["min_quality"] is not None and not 0.0 <= fracture["min_quality"] < 1.0:
        raise SceneError(f"fracture.min_quality: must be in [0, 1), got {fracture['min_quality']}")
    return fracture


def blade_path(cut: dict) -> np.ndarray:
    """(F, 2, 3) blade endpoints (m) at every frame from the first key frame to the last."""
    keys = np.asarray(cut["frames"], dtype=np.float64)
    frames = np.arange(cut["frames"][0], cut["frames"][-1] + 1, dtype=np.float64)
    flat = cut["blade"].reshape(len(keys), 6)
    return np.stack([np.interp(frames, keys, flat[:, c]) for c in range(6)], axis=1).reshape(-1, 2, 3)


def build_mesh(scene: Scene):
    """The scene's mesh: loaded (path relative to the scene file) or generated. A
    :class:`~wcut.mesh.ShellMesh` for a sheet generator or a file of triangles without
    tetrahedra; else a :class:`~wcut.mesh.TetMesh`, or a
    :class:`~wcut.quadratic.QuadraticTetMesh` when ``mesh.order = 2``."""
    from . import mesh as meshes
    from .quadratic import load_mesh, to_quadratic

    m = scene.mesh
    if m["path"] is not None:
        path = scene.path.parent / m["path"]
        if not _is_shell_file(path):
            if m["thickness"] is not None:
                raise SceneError(f"{scene.path.name}: mesh.thickness: only for shells, and {m['path']} holds "
                                 f"tetrahedra")
            return load_mesh(path, m["order"] or 1)
        if m["order"] not in (None, 2):
            raise SceneError(f"{scene.path.name}: mesh.order: {m['path']} holds triangles (a shell), which are "
                             f"always quadratic: expected 2 or no mesh.order, got {m['order']}")
        return meshes.ShellMesh.load(path)
    common = {"origin": m["origin"], "pattern": m["pattern"]}
    if m["generator"] == "rectangle_sheet":
        return meshes.rectangle_sheet(*m["cells"], size=m["size"], **common)
    if m["generator"] == "l_shape_sheet":
        return meshes.l_shape_sheet(m["cells"][0] // 2, size=m["size"][0], **common)
    if m["generator"] == "precut_sheet":
        return meshes.precut_sheet(*m["cells"], size=m["size"], notch_length=m["notch_length"], **common)
    mesh = meshes.beam(*m["cells"], size=m["size"], origin=m["origin"], tets_per_hex=m["tets_per_hex"])
    return to_quadratic(mesh) if m["order"] == 2 else mesh


def _is_shell_file(path) -> bool:
    """Whether a mesh file is a shell: triangles (``triangle`` or ``triangle6``) and no
    tetrahedra. False when it cannot be read: the tetrahedral loader reports why."""
    from .errors import MeshError
    from .mesh import read_meshio

    try:
        kinds = {block.type for block in read_meshio(path).cells}
    except MeshError:
        return False
    return not kinds & {"tetra", "tetra10"} and bool(kinds & {"triangle", "triangle6"})


def build_model(scene: Scene, mesh=None, device=None):
    """Model, Control and external nodal forces (N, (N, 3) numpy) of a scene."""
    model, control, forces, _ = _build(scene, mesh, device)
    return model, control, forces


def _build(scene: Scene, mesh=None, device=None):
    """:func:`build_model` and the attachment targets' :class:`TargetMotion`."""
    from .mesh import ShellMesh
    from .model import Attachments, Model

    where = scene.path.name
    mesh = mesh if mesh is not None else build_mesh(scene)
    is_shell = isinstance(mesh, ShellMesh)
    c = scene.constraints

    def vertex(index: int, key: str) -> int:  # indices in a scene are the mesh file's numbering
        found = mesh.vertex_from_source(index)
        if found < 0:
            kind = "shell" if is_shell else "tetrahedral"
            raise SceneError(f"{where}: {key}: vertex {index} is not a vertex of the {kind} mesh")
        return found

    fixed = [np.array([vertex(i, "constraints.fixed_indices") for i in c["fixed_indices"]], dtype=np.int64)]
    for i, box in enumerate(c["fixed_boxes"]):
        fixed.append(mesh.vertices_in_box(*box))
        if len(fixed[-1]) == 0:
            raise SceneError(f"{where}: constraints.fixed_boxes[{i}] contains no vertex")
    attached, targets, velocities, tracks = Attachments.empty(), [], [], []
    for i, a in enumerate(scene.attachments):
        if a["box"] is not None:
            ids = mesh.vertices_in_box(*a["box"])
            if len(ids) == 0:
                raise SceneError(f"{where}: attachments[{i}].box contains no vertex")
            held = Attachments.at_vertices(ids, a["stiffness"])
            targets.append(mesh.vertices[ids])
        elif a["vertex"] is not None:
            held = Attachments.at_vertices([vertex(a["vertex"], f"attachments[{i}].vertex")], a["stiffness"])
            targets.append([a["target"]])
        else:
            held = Attachments.at_points(mesh, [a["point"]], a["stiffness"])
            targets.append([a["target"]])
        attached = attached.concatenate(held)
        velocities.append(np.broadcast_to(np.asarray(a["velocity"], float), (len(held), 3)))
        if a["keyframes"] is not None:
            tracks.append((sum(len(v) for v in velocities[:-1]), len(held), a["keyframes"]))
    thickness = scene.mesh["thickness"]
    shell = {"thickness": DEFAULT_THICKNESS if thickness is None else thickness} if is_shell else {}
    model = Model(mesh, **scene.material, **scene.damping, gravity=scene.loads["gravity"],
                  fixed=np.unique(np.concatenate(fixed)), attachments=attached, device=device, **shell)
    control = model.control()
    if len(scene.attachments):
        control.attachment_target.assign(np.concatenate(targets).astype(np.float32))
    forces = np.zeros((mesh.vertex_count, 3))
    for i, f in enumerate(scene.forces):
        ids = mesh.vertices_in_box(*f["box"])
        if len(ids) == 0:
            raise SceneError(f"{where}: loads.force[{i}].box contains no vertex")
        forces[ids] += np.asarray(f["total"]) / len(ids)
    velocity = np.concatenate(velocities) if velocities else np.zeros((0, 3))
    return model, control, forces, TargetMotion(velocity, tracks)


@dataclass
class TargetMotion:
    """How the attachment targets move: ``offset(t)`` (S, 3) (m) from their start at time t (s).

    Attributes:
        velocity: (S, 3) constant velocities (m/s).
        tracks: ``(first, count, keyframes)``: attachments ``first .. first + count - 1``
            follow the (K, 4) ``[t, dx, dy, dz]`` rows, linear in between, held after the last.
    """

    velocity: np.ndarray
    tracks: list

    @property
    def moving(self) -> bool:
        return bool(np.any(self.velocity)) or bool(self.tracks)

    def offset(self, time: float) -> np.ndarray:
        out = time * self.velocity
        for first, count, keys in self.tracks:
            out[first:first + count] += [np.interp(time, keys[:, 0], keys[:, c]) for c in (1, 2, 3)]
        return out


@dataclass
class RunResult:
    """What :func:`run_scene` reports."""

    frames: int
    steps: int
    mean_step_ms: float
    nodes: int
    elements: int  #: tetrahedra of a solid, triangles of a shell
    output: Path | None
    cut_events: int = 0
    crack_events: int = 0  #: crack advances (:class:`wcut.fracture.CrackEvent`)
    #: simulated time over the wall time of the steps, crack growth and cut events
    real_time_factor: float = 0.0


class Simulation:
    """A scene being simulated, frame by frame: the model, its state, the blade and the
    fracture driver, and the topological changes they make.

    Each frame advances ``1 / fps`` seconds in ``ceil(1 / (fps * dt))`` equal sub-steps.
    Attachments with a ``velocity`` or ``keyframes`` move their targets (:class:`TargetMotion`).

    Attributes:
        model, state, control, solver: the current model and its state (rebuilt after every
            topological change).
        frame: frames simulated so far.
        step_seconds: wall time spent in solver steps and crack growth (s).
        cut_seconds: wall time spent in the blade's cut events (cut and rebuild, s).
        cut_events: frames in which the blade changed the mesh.
        changes: the ``(mesh, change)`` of every topological change of the last frame, in order.
    """

    def __init__(self, scene: Scene, device=None):
        self.scene = scene
        self.model, self.control, forces, self._motion = _build(scene, device=device)
        if scene.cut and self.model.tri_count:
            raise SceneError(f"{scene.path.name}: cut: a blade cuts solids only; this scene's mesh is a shell")
        if scene.fracture and not self.model.tri_count:
            raise SceneError(f"{scene.path.name}: fracture: fracture is simulated on shells only; this scene's "
                             f"mesh is a solid")
        self._settings = scene.solver
        self.solver = self._solver()
        fps = scene.simulation["fps"]
        self.substeps = max(1, math.ceil(1.0 / (fps * (self._settings["dt"] or 1.0 / fps)) - 1e-9))
        self.dt = 1.0 / (fps * self.substeps)
        self.state, self._next = self.model.state(), self.model.state()
        for each in (self.state, self._next):  # constant loads: the solver reads them and never clears them
            each.particle_f.assign(forces.astype(np.float32))
        self.blade = _Blade(scene.cut, self.model.mesh) if scene.cut else None
        self.fracture = _fracture(scene.fracture, self.model.mesh) if scene.fracture else None
        self._targets0 = self.control.attachment_target.numpy().astype(np.float64)
        self._moving = self._motion.moving
        self.frame, self.step_seconds, self.cut_seconds, self.cut_events = 0, 0.0, 0.0, 0
        self.changes: list = []

    def _solver(self):
        from .solver import SolverCorotational

        s = self._settings
        given = {key: s[key] for key in ("cg_iterations", "cg_tolerance") if s[key] is not None}
        return SolverCorotational(self.model, **given, preconditioner=s["preconditioner"],
                                  rotation_iterations=s["rotation_iterations"],
                                  rotation_stiffness=s["rotation_stiffness"], cpu_threads=s["cpu_threads"])

    def rebuild(self, mesh, change) -> None:
        """Carry the model, states, control and solver over ``change`` (which led to ``mesh``)."""
        self.changes.append((mesh, change))
        self.model, self.solver, (self.state, self._next), self.control = apply_change(
            mesh, change, self.model, self.solver, (self.state, self._next), self.control)

    def advance(self) -> bool:
        """Simulate one frame; True when the mesh changed (a cut or a crack)."""
        import warp as wp

        start, changed = time.perf_counter(), False
        self.changes = []
        for substep in range(self.substeps):
            if self._moving:  # grabbed points move with their velocity or keyframes
                elapsed = (self.frame * self.substeps + substep + 1) * self.dt
                self.control.attachment_target.assign(
                    (self._targets0 + self._motion.offset(elapsed)).astype(np.float32))
            self.solver.step(self.state, self._next, self.control, self.dt)
            self.state, self._next = self._next, self.state
            change = self.fracture.step(self.model, self.state) if self.fracture else None
            if change is not None:  # a crack advances after every step, at most a bounded number of edges
                changed = True
                self.rebuild(self.fracture.mesh, change)
        wp.synchronize_device(self.model.device)
        self.step_seconds += time.perf_counter() - start
        self.solver.check()
        self.frame += 1
        start = time.perf_counter()
        change = self.blade.cut_frame(self.frame, self.state) if self.blade else None
        if change is not None:
            self.cut_events += 1
            self.rebuild(self.blade.mesh(), change)
        self.cut_seconds += time.perf_counter() - start
        return changed or change is not None


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
    from .stress import vertex_von_mises
    from .usd import UsdAnimationWriter, stress_colors

    frames = scene.frame_count if frames is None else frames
    if frames < 1:
        raise SceneError(f"frames must be at least 1, got {frames}")
    output = Path(output or scene.output["path"] or f"{scene.name}.usdc")
    writer = UsdAnimationWriter(output, fps=scene.simulation["fps"], up_axis=scene.output["up_axis"])
    check_writable(output)  # fail before the simulation, not after it
    sim = Simulation(scene, device=device)
    subdivision = scene.output["subdivision"]
    surface = render_surface(sim.model.mesh, subdivision)
    colored = scene.output["stress_colors"]
    # Frames are kept until the end so that every frame is coloured on one stress scale.
    points, triangles, stresses = [], [], []

    def record():
        points.append(surface.points(sim.state.particle_q.numpy()))
        triangles.append(surface.triangles)
        if colored:  # quadratic interpolation may undershoot 0 between nodes
            stresses.append(np.maximum(surface.points(vertex_von_mises(sim.model, sim.state)), 0.0))

    show = sys.stderr.isatty() if progress is None else progress
    bar = _progress(frames, show, scene.name)
    record()
    try:
        for _ in range(frames):
            if sim.advance():
                surface = render_surface(sim.model.mesh, subdivision)
            record()
            bar.update(1)
    finally:
        bar.close()
    stress_max = scene.output["stress_max"] or (max(float(v.max()) for v in stresses) if colored else 0.0)
    with writer:
        for frame, frame_points in enumerate(points):
            colors = stress_colors(stresses[frame], vmin=0.0, vmax=max(stress_max, 1e-30)) if colored else None
            writer.write_frame(scene.name, frame, frame_points, triangles[frame], colors)
    wall = sim.step_seconds + sim.cut_seconds
    return RunResult(frames=frames, steps=frames * sim.substeps,
                     mean_step_ms=1e3 * sim.step_seconds / (frames * sim.substeps),
                     real_time_factor=frames / scene.simulation["fps"] / wall if wall > 0 else float("inf"),
                     nodes=sim.model.particle_count, elements=sim.model.tri_count or sim.model.tet_count,
                     output=output, cut_events=sim.cut_events,
                     crack_events=len(sim.fracture.events) if sim.fracture else 0)


def _fracture(settings: dict, mesh):
    """The :class:`wcut.fracture.ShellFracture` of a scene's [fracture] table."""
    from .fracture import ShellFracture

    return ShellFracture(mesh, settings["strength"], variant=settings["variant"],
                         max_cracks_per_step=settings["max_cracks_per_step"], smoothing=settings["smoothing"],
                         direction_smoothing=settings["direction_smoothing"], min_quality=settings["min_quality"])


def render_surface(mesh, subdivision: int = 2):
    """What is written of a mesh's boundary: its triangles (linear mesh) or its curved faces
    tessellated ``subdivision`` times (quadratic mesh, shell); a
    :class:`~wcut.quadratic.SurfaceTessellation`."""
    from .mesh import ShellMesh
    from .quadratic import SurfaceTessellation

    if getattr(mesh, "order", 1) == 2 or isinstance(mesh, ShellMesh):
        return mesh.surface_tessellation(subdivision)
    return SurfaceTessellation.of_linear(mesh)


class _Blade(Blade):
    """The scene's blade: a :class:`wcut.Blade` moved along the scene's path, one position per
    frame from the cut's first frame."""

    def __init__(self, cut: dict, mesh):
        from .cut import SweptBlade

        super().__init__(mesh, method=cut["method"], epsilon=cut["epsilon"], improve=cut["improve"])
        self.first = cut["frames"][0]
        self.sweep = SweptBlade(blade_path(cut))
        length = float(np.linalg.norm(self.sweep.blade[:, 1] - self.sweep.blade[:, 0], axis=1).max())
        self.samples = sample_count(length, self.cutter.mean_edge_length)

    def cut_frame(self, frame: int, state):
        """The TopologyChange of this frame's cut, or None when nothing changed."""
        k = frame - self.first
        if not 0 <= k < self.sweep.frame_count:
            self.last_increment = None
            return None
        return self.cut(state, *self.sweep.blade[k])


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


__all__ = ["Scene", "RunResult", "Simulation", "load_scene", "build_mesh", "build_model", "run_scene", "WcutError"]
