"""``warp-shape view FILE.rrd``: open a recording (``--rerun``) in the rerun viewer."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

__all__ = ["register", "run", "viewer_command"]


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
    from ..errors import WarpShapeError

    p = Path(path)
    if not p.is_file():
        raise WarpShapeError(f"no recording at {p}; write one with --rerun FILE.rrd (e.g. warp-shape design "
                             f"--rerun out/design.rrd)")
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise WarpShapeError("viewing recordings needs rerun-sdk: pip install 'warp-shape[rerun]' "
                             "(or open the file with any rerun viewer of the same version)") from None
    return [sys.executable, "-m", "rerun", str(p)]


def run(args) -> int:
    """Start the viewer on the recording and wait for it to close."""
    from ..errors import WarpShapeError

    cmd = viewer_command(args.path)
    print(f"opening {args.path} in the rerun viewer ...", file=sys.stderr)
    try:
        return subprocess.call(cmd)
    except OSError as exc:
        raise WarpShapeError(f"could not start the rerun viewer ({exc})") from None
