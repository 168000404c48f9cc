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
