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
