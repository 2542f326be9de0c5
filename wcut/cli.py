"""The ``wcut`` command (contract in DESIGN.md).

Every :class:`wcut.WcutError` is printed as one line ``wcut: error: ...`` on standard error
with exit status 2; output files are written atomically, so a failed run leaves none behind.
"""

from __future__ import annotations

import argparse
import os
import sys

from . import __version__
from .errors import WcutError


def _cmd_run(args) -> int:
    from .scene import load_scene, run_scene

    scene = load_scene(args.scene)
    result = run_scene(scene, args.output, frames=args.frames, progress=None if not args.quiet else False)
    print(f"frames: {result.frames}")
    print(f"mean step: {result.mean_step_ms:.3f} ms ({result.steps} steps)")
    print(f"nodes: {result.nodes}")
    print(f"elements: {result.elements}")
    print(f"wrote {result.output}")
    return 0


def _cmd_bench(args) -> int:
    from .bench import run_benchmarks

    run_benchmarks(json_path=args.json, quick=args.quick, progress=not args.quiet)
    return 0


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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

    bench = sub.add_parser("bench", help="run the kernel and solver benchmarks",
                           description="Time the kernels and a full step on SOFA's benchmark beams, "
                                       "side by side with a scipy reference implementation.")
    bench.add_argument("--json", metavar="OUT.json", help="also write the results as JSON")
    bench.add_argument("--quick", action="store_true", help="fewer repetitions (a smoke run)")
    bench.add_argument("--quiet", action="store_true", help="no progress bar")
    bench.set_defaults(func=_cmd_bench)
    return parser


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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    _init_warp_quietly()
    try:
        return args.func(args)
    except WcutError as exc:
        message = " ".join(str(exc).split())
        print(f"wcut: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("wcut: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
