#!/usr/bin/env python3
"""Compile every kernel module of wcut for CUDA, without a GPU: a check that the kernels stay valid CUDA.

The kernels run on Warp's CPU backend here, and this machine has no GPU; a kernel can
still be written so that only the CPU compiler accepts it (a builtin without a CUDA
overload, a host-only construct). Warp compiles a module for a GPU architecture ahead of
time with NVRTC, which its wheel ships, without a driver or a device: this tool does that
for every module of ``wcut.kernels`` (PTX, sm_90 by default: the H100) and reports the time
each took. It checks that the CUDA code generates and compiles, not that it runs or gives
the CPU's results: that needs a GPU (the ``device`` tool, when one is lent).

Run::

    .venv/bin/python tools/cuda_compile.py [--arch 90] [MODULE ...]

Exit status 0 when every module compiles, 1 otherwise (the error printed), 2 when NVRTC is
not available.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import tempfile
import time


def kernel_modules() -> list[str]:
    """The names of the modules of ``wcut.kernels`` that define kernels (a module of functions
    only, ``ranges``, is compiled into the modules whose kernels call it)."""
    import warp as wp

    import wcut.kernels

    def has_kernels(name: str) -> bool:
        module = importlib.import_module(f"wcut.kernels.{name}")
        return any(isinstance(value, wp.Kernel) for value in vars(module).values())

    return sorted(m.name for m in pkgutil.iter_modules(wcut.kernels.__path__) if has_kernels(m.name))


def nvrtc_archs() -> list[int]:
    """The CUDA architectures Warp's NVRTC compiles for (none without CUDA support)."""
    import warp as wp

    wp.init()
    runtime = wp._src.context.runtime  # Warp has no public query for this without a device
    return sorted(getattr(runtime, "nvrtc_supported_archs", None) or [])


def compile_for_cuda(name: str, arch: int, directory: str) -> float:
    """Compile module ``wcut.kernels.<name>`` to PTX for ``sm_<arch>`` into ``directory``;
    the seconds it took. Raises whatever Warp raises when code generation or NVRTC fails."""
    import warp as wp

    module = importlib.import_module(f"wcut.kernels.{name}")
    start = time.perf_counter()
    wp.compile_aot_module(module, arch=arch, module_dir=directory, use_ptx=True)
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("modules", nargs="*", help="modules of wcut.kernels (default: all)")
    parser.add_argument("--arch", type=int, default=90, help="CUDA architecture, e.g. 90 for sm_90 (default)")
    args = parser.parse_args(argv)

    import warp as wp

    wp.config.quiet = True
    archs = nvrtc_archs()
    if args.arch not in archs:
        print(f"NVRTC cannot compile for sm_{args.arch} in this Warp build (it can for: "
              f"{', '.join(f'sm_{a}' for a in archs) or 'none'})", file=sys.stderr)
        return 2
    names = args.modules or kernel_modules()
    unknown = sorted(set(names) - set(kernel_modules()))
    if unknown:
        print(f"not a module of wcut.kernels: {', '.join(unknown)}", file=sys.stderr)
        return 2
    failed = []
    with tempfile.TemporaryDirectory(prefix="wcut-cuda-") as directory:
        for name in names:
            try:
                seconds = compile_for_cuda(name, args.arch, directory)
            except Exception as error:  # noqa: BLE001 - every failure is reported, the others go on
                failed.append(name)
                print(f"{name:16s} FAILED: {type(error).__name__}: {error}")
            else:
                print(f"{name:16s} sm_{args.arch} PTX in {seconds:6.1f} s")
    if failed:
        print(f"{len(failed)} of {len(names)} modules do not compile for CUDA: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
