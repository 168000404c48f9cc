"""Actuator families: what a kind of actuator adds to a design, its model, its controls and its files.

An ``ActuatorFamily`` declares, for its elements (``Design.elements(name)``): the host arrays
(``HostModel.actuators[name]``), the device arrays (``Model.actuators[name]``), one float64 control
per element and world (``Control.values[name]``, with the mask ``Control.enabled[name]``), the
force launch ``eval_forces`` (skipping empty work), the float64 energy, the stiffness bound rows
and elastic operator terms of the stable-step estimate, the values a precision must hold, what it
adds to an observation and to the control record, its scene attributes (one prim of the design
holding one array element per element) and its neutral control (what a control law that does not
know the family holds it at). The simulator, the force passes, the stable-step estimate, the
controller's observation and record and the scene reader and writer loop over
``ACTUATOR_FAMILIES``; the IPAM (``physics/ipam.py``) is its first member, and a family registered
from outside the package (``ACTUATOR_FAMILIES.register``, e.g. in a module named in
``WARP_SHAPE_PLUGINS``) is stepped, controlled and saved like it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .force_family import ForceFamily
from .registry import Registry

__all__ = ["ActuatorFamily", "ACTUATOR_FAMILIES", "SceneAttribute", "families", "SCENE_NAMESPACE"]

#: namespace of every warp_shape scene attribute (``warpShape:<name>``)
SCENE_NAMESPACE = "warpShape"


@dataclass(frozen=True)
class SceneAttribute:
    """One row of a scene's attribute table: a USD attribute and the field it holds.

    ``name``: the attribute name. ``usd_type``: its Sdf value type name (``double``,
    ``double[]``, ``double2[]``, ``int2[]``). ``field``: the ``Material`` field or the element's
    field (an IPAM's ``faces`` is the pair (face_a, face_b)). ``width``: numbers per array element
    (1 for scalars and plain arrays). ``required``: read on loading; False for derived values,
    written for other tools and recomputed on loading.
    """

    name: str
    usd_type: str
    field: str
    width: int
    required: bool

    @property
    def is_array(self) -> bool:
        """True for an array attribute (one or more values per element)."""
        return self.usd_type.endswith("[]")

    @property
    def is_integer(self) -> bool:
        """True for integer attributes (face and vertex indices)."""
        return self.usd_type.startswith("int")


class ActuatorFamily(ForceFamily):
    """A kind of actuator: a force family (``force_family.ForceFamily``: arrays, forces, energy,
    stable-step terms, adjoint) whose elements each take one control per world. Subclasses set the
    class attributes and implement the methods that raise ``NotImplementedError``; the others have
    defaults that add nothing.

    ``control_unit``: the unit of its control (e.g. "Pa", "m"). ``scene_prim``: the prim under the
    scene's default prim holding its elements; ``scene_attributes``: its attribute table (the first
    row is the one every other row's length is checked against). ``history_columns``: the record's
    per-element columns, ``{i}`` the element index; the first is its control, which a replay of the
    record sets row by row. ``color``: its display colour in scenes.
    """

    label = "actuator"
    plural = "actuators"
    owner = "the actuator's constructor"  # where a storability error says to change a value
    controlled = True
    control_unit = ""
    control_name = "control"  # what messages call its control ("pressure")
    limits_name = "its limits"  # what messages call the limits of its control ("pressure_limits")
    scene_prim = ""
    scene_attributes: tuple = ()
    history_columns: tuple = ()
    color = (0.08, 0.08, 0.08)

    @property
    def control_column(self) -> str:
        """The history column of element ``{i}``'s control (the first of ``history_columns``)."""
        return self.history_columns[0] if self.history_columns else ""

    def control_limits(self, host: dict) -> np.ndarray | None:
        """(n, 2) allowed range of each element's control, or None when any finite value is allowed."""
        return None

    # ------------------------------------------------------------------ controller
    def observe(self, dev, x: np.ndarray, sampled: np.ndarray, centroids: np.ndarray, target_centroids: np.ndarray,
                controls: np.ndarray) -> dict:
        """{quantity: (W, n) array} this family adds to an observation of the host model ``dev`` at
        positions x (W, V, 3), the sampled target (W, V, 3), their face centroids (W, F, 3) and
        controls (W, n) (its host arrays: ``dev.actuators[name]``)."""
        return {}

    def history_row(self, observed: dict, controls: np.ndarray, w: int, host: dict) -> dict:
        """World ``w``'s values of ``history_columns`` from its observation part and controls (W, n)."""
        return {}

    def neutral_controls(self, host: dict, observed: dict, controls: np.ndarray) -> np.ndarray:
        """(W, n) the controls a law that does not know this family holds it at (default: unchanged)."""
        return controls

    # ------------------------------------------------------------------ scenes
    def curve_ends(self, design, positions: np.ndarray) -> np.ndarray:
        """(n, 2, 3) the two ends each element is drawn between at positions (V, 3); (..., n, 2, 3)
        (or (..., 2 n, 3)) for stacked positions (..., V, 3), e.g. the frames of an animation."""
        raise NotImplementedError

    def curve_widths(self, design) -> np.ndarray:
        """(n,) display width of each element in m."""
        return np.full(self.count(design), 1e-3)

    def attribute_values(self, design, attr: SceneAttribute) -> np.ndarray:
        """Values of ``attr`` over every element of ``design``: (n,) or (n, width) arrays (int32 for
        indices, float64 otherwise)."""
        flat = np.concatenate([np.asarray(getattr(e, attr.field)).reshape(-1) for e in design.elements(self.name)])
        flat = flat.astype(np.int32 if attr.is_integer else np.float64)
        return flat if attr.width == 1 else flat.reshape(-1, attr.width)

    def check_scene_values(self, design, values: dict) -> str | None:
        """A message for element values read from a scene that cannot be added (indices out of range),
        naming the element, or None. ``values``: {field: array} of the required attributes."""
        return None

    def add_from_scene(self, design, values: dict, i: int) -> None:
        """Add element ``i`` of the required attributes' arrays ``values`` to ``design``."""
        raise NotImplementedError


#: every actuator family, the IPAM first (registered by ``physics/ipam.py``)
ACTUATOR_FAMILIES = Registry("actuator family")


def families() -> tuple:
    """The registered families, in registration order."""
    return tuple(ACTUATOR_FAMILIES.get(n) for n in ACTUATOR_FAMILIES)
