"""``warp-shape view FILE.rrd``: open a recording (``--rerun``) in the rerun viewer."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from ..errors import WarpShapeError
from ..io.recording_read import check_recording_file

__all__ = ["register", "run", "viewer_command", "display_problem"]

#: The viewer's own server (for SDKs streaming to it) listens on this machine only, never on a network.
VIEWER_BIND = "127.0.0.1"


def register(subparsers) -> None:
    """Add the ``view`` subcommand."""
    v = subparsers.add_parser("view", help="open a recording (--rerun FILE.rrd) in the rerun viewer",
                              description="Open a rerun recording written with --rerun in the rerun viewer "
                                          "(needs rerun-sdk: pip install 'warp-shape[rerun]', and a display).")
    v.add_argument("path", help="the recording, a .rrd file")
    v.set_defaults(func=run)


def viewer_command(path) -> list[str]:
    """The command that opens ``path`` in the rerun viewer of this Python's rerun-sdk; a clear error
    where the file or rerun-sdk is missing."""
    p = Path(path)
    check_recording_file(p)
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise WarpShapeError("viewing recordings needs rerun-sdk: pip install 'warp-shape[rerun]' "
                             "(or open the file with any rerun viewer of the same version)") from None
    return [sys.executable, "-m", "rerun", str(p), "--bind", VIEWER_BIND]


def display_problem(path) -> str | None:
    """Why the viewer could open no window here (a Linux machine with neither an X nor a Wayland
    display), with how to open ``path`` elsewhere; None where there is a display."""
    if not sys.platform.startswith("linux") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    import rerun  # optional (rerun-sdk) and ~1 s to import: only here, never at start-up

    return (f"no display here (DISPLAY and WAYLAND_DISPLAY are unset), so the viewer cannot open a window; copy "
            f"{path} to a machine with one and open it there: pip install rerun-sdk=={rerun.__version__}; "
            f"rerun {Path(path).name}")


def run(args) -> int:
    """Start the viewer on the recording and wait for it to close."""
    cmd = viewer_command(args.path)
    problem = display_problem(args.path)
    if problem:
        raise WarpShapeError(problem)
    print(f"opening {args.path} in the rerun viewer ...", file=sys.stderr)
    try:
        status = subprocess.call(cmd)
    except OSError as exc:
        raise WarpShapeError(f"could not start the rerun viewer ({exc})") from None
    if status != 0:
        print(f"warp-shape view: the rerun viewer ended with exit status {status} (its own messages above); "
              f"{args.path} is unchanged: open it with rerun on another machine if this one cannot show it",
              file=sys.stderr)
    return status
