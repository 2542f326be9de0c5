"""The ``wcut`` command (contract in DESIGN.md).

Every :class:`wcut.WcutError` is printed as one line ``wcut: error: ...`` on standard error
with exit status 2; output files are written atomically, so a failed run leaves none behind.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from . import __version__
from .errors import MeshNotice, WcutError


def _cmd_run(args) -> int:
    from .scene import load_scene, run_scene

    scene = load_scene(args.scene)
    result = run_scene(scene, args.output, frames=args.frames, progress=None if not args.quiet else False)
    print(f"frames: {result.frames}")
    print(f"mean step: {result.mean_step_ms:.3f} ms ({result.steps} steps)")
    print(f"real-time factor: {result.real_time_factor:.2f} (simulated time / wall time of the steps and cut events)")
    print(f"nodes: {result.nodes}")
    print(f"elements: {result.elements}")
    if result.crack_events:
        print(f"crack advances: {result.crack_events}")
    print(f"wrote {result.output}")
    return 0


def _cmd_bench(args) -> int:
    from .bench import run_benchmarks

    run_benchmarks(json_path=args.json, quick=args.quick, progress=not args.quiet)
    return 0


def _cmd_cut(args) -> int:
    from .cut.command import run_cut

    report = run_cut(args.mesh, args.output, plane=args.plane, surface=args.surface, method=args.method,
                     epsilon=args.epsilon, order=args.order, report_path=args.report)
    print(f"nodes: {report['nodes_before']} -> {report['nodes_after']}")
    print(f"elements: {report['elements_before']} -> {report['elements_after']} ({report['cut_elements']} cut)")
    print(f"volume: {report['volume_before']:.9g} -> {report['volume_after']:.9g} m^3")
    print(f"min dihedral: {report['min_dihedral_deg']:.2f} deg")
    print(f"components: {report['components']}")
    print(f"wrote {args.output}")
    return 0


def _cmd_synth(args) -> int:
    from .ar.synth import synthesize

    result = synthesize(args.scene, args.output, frames=args.frames, progress=None if not args.quiet else False)
    print(f"frames: {result.frames}")
    print(f"truth elements: {result.truth_elements}")
    print(f"model elements: {result.model_elements}")
    print(f"cut frames: {', '.join(map(str, result.cut_frames)) or 'none'}")
    print(f"wrote {result.directory}")
    return 0


def _cmd_ar(args) -> int:
    from .ar.pipeline import run_ar

    result = run_ar(args.capture, args.output, overlay=args.overlay, metrics=args.metrics, cut=not args.no_cut,
                    frames=args.frames, progress=None if not args.quiet else False)
    m = result.metrics()
    print(f"frames: {m['frames']}")
    print(f"features: {m['features']} ({m['features_lost']} lost)")
    print(f"cuts detected: {m['cuts_detected']}" + (" (cut handling off)" if args.no_cut else ""))
    if m["dice_final"] is not None:
        print(f"dice final: {m['dice_final']:.4f}")
    print(f"detection: {m['detection_ms_mean']:.3f} ms/frame")
    print(f"loop: {m['fps_mean']:.1f} frames/s")
    for path in (args.output, args.overlay, args.metrics):
        if path:
            print(f"wrote {path}")
    return 0


def _epsilon(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0.0 <= value < 0.5:
        raise argparse.ArgumentTypeError(f"expected a value in [0, 0.5), got {value}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse with the contract's errors: one line ``wcut: error: ...`` and exit 2."""

    def error(self, message: str):
        self.exit(2, f"wcut: error: {self.prog.removeprefix('wcut ')}: {message}\n" if self.prog != "wcut"
                  else f"wcut: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="wcut", description="Real-time cutting, tearing and fracture of deformable objects (Warp FEM).")
    parser.add_argument("--version", action="version", version=f"wcut {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = sub.add_parser("run", help="run a scene and write its USD animation",
                         description="Run a scene file (TOML) and write the animation as USD.")
    run.add_argument("scene", metavar="SCENE.toml")
    run.add_argument("-o", "--output", metavar="OUT.usd|.usda|.usdc",
                     help="output file (default: the scene's output.path, else <name>.usdc)")
    run.add_argument("--frames", type=_positive_int, metavar="N", help="frames to simulate (default: duration * fps)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=_cmd_run)

    cut = sub.add_parser("cut", help="cut a mesh file with a plane or a surface",
                         description="Cut a rest-configuration tetrahedral mesh (any format meshio reads), "
                                     "separate it along the cut and write the result and a JSON report.")
    cut.add_argument("mesh", metavar="MESH_IN")
    cut.add_argument("-o", "--output", metavar="MESH_OUT", required=True,
                     help="output mesh (format from the extension: .vtu, .msh, .vtk, .mesh, ...)")
    where = cut.add_mutually_exclusive_group(required=True)
    where.add_argument("--plane", metavar="px,py,pz,nx,ny,nz",
                       help="an infinite cut plane: point and normal (m); a first value below zero works as "
                            "--plane -0.01,0,0,1,0,0 or --plane=-0.01,0,0,1,0,0")
    where.add_argument("--surface", metavar="TRIS.obj", help="a triangulated cut surface (Wavefront .obj, m)")
    cut.add_argument("--method", choices=("paulus", "bielser", "snap", "delete"), default="paulus",
                     help="remeshing method (default: paulus, thesis chapter 5)")
    cut.add_argument("--epsilon", type=_epsilon, default=0.1, metavar="E",
                     help="snapping threshold, fraction of the mean edge length (default: 0.1)")
    cut.add_argument("--order", type=int, choices=(1, 2), default=1, help="element order (default: 1)")
    cut.add_argument("--report", metavar="R.json", help="write the cut report as JSON")
    cut.set_defaults(func=_cmd_cut)

    bench = sub.add_parser("bench", help="run the kernel and solver benchmarks",
                           description="Time the kernels and a full step on SOFA's benchmark beams, "
                                       "side by side with a scipy reference implementation.")
    bench.add_argument("--json", metavar="OUT.json", help="also write the results as JSON")
    bench.add_argument("--quick", action="store_true", help="fewer repetitions (a smoke run)")
    bench.add_argument("--quiet", action="store_true", help="no progress bar")
    bench.set_defaults(func=_cmd_bench)

    synth = sub.add_parser("synth", help="write a synthetic capture directory with ground truth",
                           description="Simulate a synthetic scene (a scene with [camera] and [synth]), render "
                                       "it through the camera and write a capture directory with truth/.")
    synth.add_argument("scene", metavar="SCENE.toml")
    synth.add_argument("-o", "--output", metavar="DIR", required=True, help="the capture directory (replaced)")
    synth.add_argument("--frames", type=_positive_int, metavar="N", help="frames after the first (default: all)")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")
    synth.set_defaults(func=_cmd_synth)

    ar = sub.add_parser("ar", help="register a model to a video and detect cuts (thesis chapter 7)",
                        description="Run the augmented-reality pipeline on a capture directory: track features, "
                                    "pull the model with springs, detect cuts and tears and cut the model; "
                                    "write the USD animation of the model and its internal structures.")
    ar.add_argument("capture", metavar="DIR")
    ar.add_argument("-o", "--output", metavar="OUT.usd|.usda|.usdc", required=True, help="the USD animation")
    ar.add_argument("--overlay", metavar="OUT.mp4|.avi", help="the frames with the model drawn over them")
    ar.add_argument("--metrics", metavar="M.json", help="per-run metrics (Dice, Hausdorff, detection, fps)")
    ar.add_argument("--no-cut", action="store_true", help="the same registration without topological changes")
    ar.add_argument("--frames", type=_positive_int, metavar="N", help="use only the first N frames")
    ar.add_argument("--quiet", action="store_true", help="no progress bar")
    ar.set_defaults(func=_cmd_ar)
    return parser


#: Commands that run Warp kernels: the first run of each compiles them (some 20 s per command
#: on two cores; a line on a terminal says so), later runs load them from Warp's cache.
COMPILING_COMMANDS = ("run", "cut", "bench", "ar", "synth")


def _init_warp_quietly() -> None:
    """Initialise Warp without its banner, and without the native CPU-only notice that no CUDA
    driver was found (printed straight to file descriptor 2); any other native message is kept."""
    import tempfile

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        for line in captured.read().decode(errors="replace").splitlines():
            if "Could not find or load the NVIDIA CUDA driver" not in line:
                print(line, file=sys.stderr)


def _compile_marker(command: str):
    """The file in Warp's kernel cache that says this command's kernels of this wcut are
    compiled (named by a digest of the kernels' sources), and whether it exists."""
    import hashlib
    from pathlib import Path

    import warp as wp

    from . import kernels

    digest = hashlib.sha1()
    for source in sorted(Path(kernels.__file__).parent.glob("*.py")):
        digest.update(source.read_bytes())
    marker = Path(wp.config.kernel_cache_dir) / f"wcut-{__version__}-{digest.hexdigest()[:12]}-{command}"
    return marker, marker.exists()


def _notices_as_lines(show):
    """``warnings.showwarning`` that prints a :class:`~wcut.errors.MeshNotice` as one line and
    passes any other warning to ``show``."""

    def shown(message, category, filename, lineno, file=None, line=None) -> None:
        if issubclass(category, MeshNotice):
            print(f"wcut: note: {message}", file=sys.stderr)
        else:
            show(message, category, filename, lineno, file, line)

    return shown


def _joined_negative_values(argv: list[str]) -> list[str]:
    """``--plane -0.01,0,0,1,0,0`` as ``--plane=-0.01,...``: argparse takes a value that starts
    with '-' and is not a plain number for an option."""
    out = []
    for i, arg in enumerate(argv):
        if i and argv[i - 1] == "--plane" and arg.startswith("-") and "," in arg:
            out[-1] = f"--plane={arg}"
        else:
            out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(_joined_negative_values(sys.argv[1:] if argv is None else list(argv)))
    if args.command is None:
        parser.print_help()
        return 2
    _init_warp_quietly()
    marker, compiled = _compile_marker(args.command)
    if not compiled and args.command in COMPILING_COMMANDS and sys.stderr.isatty():
        print("wcut: compiling kernels, once, about 20-60 s", file=sys.stderr, flush=True)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _notices_as_lines(warnings.showwarning)
            status = args.func(args)
        if not compiled and status == 0:
            marker.touch()
        return status
    except WcutError as exc:
        message = " ".join(str(exc).split())
        print(f"wcut: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("wcut: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
