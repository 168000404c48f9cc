"""Exceptions raised by warp_shape. Every message names the problem and, where there is one, the fix."""

from __future__ import annotations


class WarpShapeError(Exception):
    """Base class of every error raised on purpose by warp_shape."""


class MeshError(WarpShapeError, ValueError):
    """A mesh is not a closed, 2-manifold, outward-wound, finite triangle mesh."""


class DesignError(WarpShapeError, ValueError):
    """A design, material or actuator description is invalid."""


class StabilityError(WarpShapeError, ValueError):
    """A requested time step is beyond the stable step of the model."""


class SimulationError(WarpShapeError, RuntimeError):
    """The simulation blew up (non-finite or runaway values)."""

    def __init__(self, message: str, *, step: int | None = None, quantity: str | None = None,
                 safe_dt: float | None = None, world: int | None = None):
        super().__init__(message)
        self.step = step
        self.quantity = quantity
        self.safe_dt = safe_dt
        self.world = world


class ShapeError(WarpShapeError, ValueError):
    """A target or scan cannot be compared: not star-shaped, a ray missed, or bad metric input."""


class SceneError(WarpShapeError, ValueError):
    """A scene file (USD) cannot be read or written: unreadable, missing or mistyped attributes, bad indices.

    ``prim`` and ``attribute`` name the offending prim path and attribute where there is one.
    """

    def __init__(self, message: str, *, prim: str | None = None, attribute: str | None = None):
        super().__init__(message)
        self.prim = prim
        self.attribute = attribute


def numeric_array(value, name: str, error=None):
    """``value`` as a float64 array, refusing what is not numbers (strings, bools, objects, ragged
    nesting) with ``error`` (``DesignError`` by default) naming ``name``."""
    import numpy as np

    error = error or DesignError
    try:
        a = np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise error(f"{name} must be an array of numbers, got {type(value).__name__} ({exc})") from None
    if a.dtype.kind not in "iuf":
        what = "bools" if a.dtype.kind == "b" else f"{a.dtype} values"
        raise error(f"{name} must be an array of numbers, got {what}: "
                    f"{np.array2string(a.reshape(-1)[:3], threshold=3)}")
    return a.astype(np.float64)


def check_number(value, name: str, error=None) -> float:
    """``value`` as a finite float; bools, strings and non-finite numbers raise ``error`` (``DesignError``)."""
    import math

    import numpy as np

    error = error or DesignError
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)):
        raise error(f"{name} must be a finite number, got {value!r}")
    return float(value)


def check_whole(value, name: str, error=None) -> int:
    """``value`` as an int: a whole number (2.0 is 2); bools, strings, None and fractions (3.7 is not
    truncated to 3) raise ``error`` (``DesignError``)."""
    import math

    import numpy as np

    error = error or DesignError
    ok = not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.integer, np.floating)) \
        and (isinstance(value, (int, np.integer)) or (math.isfinite(value) and float(value).is_integer()))
    if not ok:
        raise error(f"{name} must be a whole number, got {value!r}")
    return int(value)


#: the largest input file (mesh, scan, scene, manifest, recording) read, in bytes: a bigger one is refused
#: before it is read (a 40962-vertex binary STL is 4 MB)
MAX_INPUT_BYTES = 2**30


def check_input_file(path, what: str, error=None, max_bytes: int = MAX_INPUT_BYTES) -> int:
    """The size in bytes of ``path``, an input ``what`` ("mesh file", "scene", ...), once ``os.stat`` shows it
    is a regular file of at most ``max_bytes``; a missing file, a folder, a FIFO, a device (/dev/zero) or a
    socket (symlinks followed) raises ``error`` (``WarpShapeError`` by default) before anything opens it."""
    import os
    import stat

    error = error or WarpShapeError
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{what} not found: {path}") from None
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path} is a folder, not a {what}; give the file itself")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise error(f"{path} is {kind}, not a regular file; give a {what} saved on disk")
    if st.st_size > max_bytes:
        raise error(f"{what} {path} is {st.st_size / 2**20:.0f} MiB, over the {max_bytes / 2**20:.0f} MiB that "
                    f"are read; give a smaller (decimated) file")
    return int(st.st_size)


def read_input_file(path, what: str, error=None, max_bytes: int = MAX_INPUT_BYTES) -> bytes:
    """The bytes of an input file checked by ``check_input_file`` (never more than ``max_bytes`` read; opened
    without blocking and checked again on the open file, so a path swapped for a FIFO cannot block)."""
    import os
    import stat

    check_input_file(path, what, error, max_bytes)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise (error or WarpShapeError)(f"{path} is not a regular file; give a {what} saved on disk")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:  # grew since the check
        raise (error or WarpShapeError)(f"{what} {path} is over the {max_bytes / 2**20:.0f} MiB that are read")
    return data
