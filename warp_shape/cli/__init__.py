"""The ``warp-shape`` command line: the parser of every subcommand and the entry point ``main``.

Subcommands, one module each: ``simulate``, ``design`` (the main job), ``control``, ``export``, ``feel``,
``bench``, ``compare``, ``calibrate``, ``sweep``, ``view``; ``options`` holds what they share, ``progress`` the
progress bars. Every help text shows the defaults.
"""

from __future__ import annotations

import argparse
import sys

from .. import __version__
from ..errors import WarpShapeError
from ..registry import load_plugins
from . import bench, calibrate, compare, control, design, export, feel, simulate, sweep, view
from .options import (check_bounds, check_warp_cache, interrupts_noted, outputs_in_place, quiet_warp, stop_if_interrupted,
                      write_failure)

__all__ = ["main", "build_parser"]


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help that ends each option with its default, except where there is none to show (None, a flag
    that is off) or the text already names it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default in (None, False, argparse.SUPPRESS) or "default" in text:
            return text
        return super()._get_help_string(action)


def _with_defaults(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = DefaultsHelpFormatter
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _with_defaults(child)


def build_parser() -> argparse.ArgumentParser:
    """The ``warp-shape`` argument parser with every subcommand."""
    p = argparse.ArgumentParser(prog="warp-shape", description="Simulate and design soft 3-D haptic shape displays.")
    p.add_argument("--version", action="version", version=f"warp-shape {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for module in (simulate, design, control, export, feel, bench, compare, calibrate, sweep, view):
        module.register(sub)
    _with_defaults(p)
    return p


def main(argv=None) -> int:
    """Entry point of ``warp-shape``: returns 0 on success, 2 on a clear input error, 1 where a full or
    failing disk refused a write, 130 on Ctrl-C (at any moment once this function runs). The modules
    named in ``WARP_SHAPE_PLUGINS`` are imported first (their strategies become choices)."""
    with interrupts_noted():
        try:
            return _run(argv)
        except WarpShapeError as exc:
            print(f"warp-shape: error: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            if outputs_in_place() is not None:  # after the swap: the run's work is done and whole
                print(f"\nwarp-shape: interrupted after the outputs were in place ({outputs_in_place()} holds "
                      f"this run's set, whole)", file=sys.stderr)
                return 0
            print("\nwarp-shape: interrupted", file=sys.stderr)
            return 130
        except OSError as exc:
            line = write_failure(exc)
            if line is None:
                raise
            print(f"warp-shape: error: {line}", file=sys.stderr)
            return 1


def _run(argv) -> int:
    stop_if_interrupted()  # Ctrl-C while the command started
    load_plugins()
    args = build_parser().parse_args(argv)
    check_bounds(args)
    check_warp_cache()
    if args.command != "view":  # every command's Warp: no banner, no note that this CPU has no CUDA driver
        quiet_warp(getattr(args, "verbose", False))
    rc = int(args.func(args) or 0)
    stop_if_interrupted()  # a Ctrl-C that a library caught on its way (the run ends as interrupted, not as 0)
    return rc
