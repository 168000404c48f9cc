"""The ``warp-shape`` command line: the parser of every subcommand and the entry point ``main``.

Subcommands, one module each: ``simulate``, ``design`` (the main job), ``control``, ``export``,
``bench``, ``compare``; ``options`` holds what they share.
"""

from __future__ import annotations

import argparse
import sys

from . import bench, compare, control, design, export, simulate, sweep

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    """The ``warp-shape`` argument parser with every subcommand."""
    p = argparse.ArgumentParser(prog="warp-shape", description="Simulate and design soft 3-D haptic shape displays.")
    sub = p.add_subparsers(dest="command", required=True)
    for module in (simulate, design, control, export, bench, compare, sweep):
        module.register(sub)
    return p


def main(argv=None) -> int:
    """Entry point of ``warp-shape``: returns 0 on success, 2 on a clear input error, 130 on Ctrl-C."""
    args = build_parser().parse_args(argv)
    from ..errors import WarpShapeError

    try:
        return int(args.func(args) or 0)
    except WarpShapeError as exc:
        print(f"warp-shape: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\nwarp-shape: interrupted; finished outputs were kept", file=sys.stderr)
        return 130
