#!/usr/bin/env python3
"""Render frames of a wcut USD animation to a PNG (no USD viewer needed).

    python tools/snapshot.py out/beam_sag.usdc -o out/beam_sag.png [--frames 0 45 90]

Each panel shows every mesh of the file at one frame, coloured by its displayColor primvar
(von Mises stress) when present, seen from the same camera.
"""

from __future__ import annotations

import argparse
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402
from pxr import Usd, UsdGeom  # noqa: E402


def meshes_at(stage, frame):
    """(points (N,3), triangles (F,3), colours (N,3) or None) of every mesh at a time code."""
    time = Usd.TimeCode(frame)
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        points = np.asarray(mesh.GetPointsAttr().Get(time), dtype=float)
        triangles = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time), dtype=int).reshape(-1, 3)
        colors = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        values = colors.Get(time) if colors and colors.HasValue() else None
        yield points, triangles, None if values is None else np.asarray(values, dtype=float)


def render(path: str, output: str, frames: list[float] | None, view: tuple[float, float] = (15.0, -60.0)) -> None:
    stage = Usd.Stage.Open(path)
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    frames = frames or [start, 0.5 * (start + end), end]
    frames = [round(f) for f in frames]
    fps = stage.GetFramesPerSecond() or 30.0
    data = {f: list(meshes_at(stage, f)) for f in frames}
    every = np.concatenate([p for meshes in data.values() for p, _, _ in meshes])
    lo, hi = every.min(axis=0), every.max(axis=0)
    center, radius = 0.5 * (lo + hi), 0.5 * (hi - lo).max()
    fig = plt.figure(figsize=(4.5 * len(frames), 4.5))
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for k, frame in enumerate(frames):
        ax = fig.add_subplot(1, len(frames), k + 1, projection="3d")
        for points, triangles, colors in data[frame]:
            corners = points[triangles]
            normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-30
            shade = 0.45 + 0.55 * np.clip(normals @ light, 0.0, 1.0)
            base = colors[triangles].mean(axis=1) ** (1 / 2.2) if colors is not None else np.full((len(triangles), 3), 0.7)
            ax.add_collection3d(Poly3DCollection(corners, facecolors=np.clip(base * shade[:, None], 0, 1),
                                                 edgecolors=(0, 0, 0, 0.15), linewidths=0.2))
        for axis, set_lim in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
            set_lim(center[axis] - radius, center[axis] + radius)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=view[0], azim=view[1])
        ax.set_title(f"frame {frame}  (t = {frame / fps:.2f} s)")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
    fig.suptitle(f"{path}  (colour: von Mises stress, dark = low)" if any(
        c is not None for meshes in data.values() for _, _, c in meshes) else path)
    fig.tight_layout()
    fig.savefig(output, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("usd")
    parser.add_argument("-o", "--output", required=True, help="PNG file")
    parser.add_argument("--frames", type=float, nargs="+", help="time codes (default: first, middle, last)")
    parser.add_argument("--view", type=float, nargs=2, default=(15.0, -60.0), metavar=("ELEV", "AZIM"),
                        help="camera elevation and azimuth in degrees (default 15 -60)")
    args = parser.parse_args(argv)
    render(args.usd, args.output, args.frames, tuple(args.view))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
