"""Force families and actuator families: what a kind of force adds to a design, its model, its
controls, its files and its gradients, in one home.

A ``ForceFamily`` declares, for its elements (``Design.elements(name)``): the float64 / int64 host
arrays (``HostModel.actuators[name]``), the device arrays (``Model.actuators[name]``), the force
launch ``eval_forces`` (skipping empty work), its float64 energy (whose negative gradient is that
force), its rows and operator terms of the stable-step estimate, its part of the static settle's
preconditioner (``diagonal_stiffness``), the values a precision must hold and, for the adjoint, the device arrays that are its parameters (``parameters``) with the launches
that derive the others from them and the rest shape (``build``). The simulator's step and read-outs
(``sim.forces(name)``, ``sim.energy()[name]``), the static settle, the stable-step estimate and the
differentiable replay (``ws.gradient``) compose every family a model holds.

A passive family (no control: a spring to a fixed anchor, a fingertip in contact) is registered in
``FORCE_FAMILIES``; an actuator family (``actuators.ActuatorFamily``, a subclass that adds one
control per element and world) in ``ACTUATOR_FAMILIES``. Either can be registered from outside the
package (``FORCE_FAMILIES.register(family)``, e.g. in a module named in ``WARP_SHAPE_PLUGINS``); the
IPAM (``physics/ipam.py``) is the first actuator family;
``tests/anchor_family.py`` is such a passive family, ``tests/toy_family.py`` such an actuator family.

The adjoint: a family whose ``eval_forces`` launches kernels built with backward enabled (Warp's
default for a ``@wp.kernel``) sets ``differentiable = True``; the differentiable replay then launches
that same ``eval_forces`` on its own device arrays (made by the family's ``device_arrays`` with
gradients), runs the kernels' adjoints in reverse, and reports d objective / d ``<family>_<parameter>``
for each name of ``parameters`` (and d objective / d ``<family>_controls`` per history row for an
actuator family). ``ws.gradient`` refuses, before any work and by name, a design holding elements of
a family that is not differentiable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .registry import Registry

__all__ = ["ForceFamily", "FORCE_FAMILIES", "force_families", "ActuatorFamily", "ACTUATOR_FAMILIES", "SceneAttribute",
           "families", "SCENE_NAMESPACE"]


class ForceFamily:
    """A kind of force. Subclasses set the class attributes and implement the methods that raise
    ``NotImplementedError``; the others have defaults that add nothing.

    ``name``: identifier (the key of its elements, arrays, force term and energy term). ``summary``:
    one line. ``label`` / ``plural``: how messages name one element / several. ``owner``: what a
    storability error names as the place to change a value. ``controlled``: whether its elements
    take a control (``ActuatorFamily``). ``differentiable``: whether ``eval_forces``'s kernels have
    adjoints (see the module's docstring); ``parameters``: {device array name: unit} of the arrays the
    gradient is taken with respect to (as ``<name>_<array>``). ``rigid_invariant``: whether its energy
    is unchanged by moving the whole membrane rigidly (forces between vertices: True); a family whose
    forces hold the membrane in space sets False, and the static settle then keeps rigid motions in
    its steps (it removes them where every force of the model is invariant)."""

    name = ""
    summary = ""
    label = "element"
    plural = "elements"
    owner = "the family's constructor"
    controlled = False
    always = False  # True: its arrays exist in every model, even with no elements (the IPAM's)
    # True: its elements hold per-world jam fields (``jam_fields``) that a jam changes (``jam``); its
    # ``energy`` then takes them as ``jam=`` and its ``stiffness_rows`` / ``operator_terms`` the edges' jam
    # flags as ``jammed=``
    jams = False
    jam_flags = "jammed"  # the jam field (W, n) int32 that is 1 where an element is jammed
    differentiable = False
    parameters: dict = {}
    scalar_parameters: tuple = ()  # names of ``parameters`` that are one value (1,) for every element
    rigid_invariant = True  # False: its forces hold the membrane in space (an anchor, an indenter, a held plug)

    # ------------------------------------------------------------------ host and device
    def count(self, design) -> int:
        """Number of this family's elements in ``design``."""
        return len(design.elements(self.name))

    def host_arrays(self, design) -> dict:
        """float64 / int64 host arrays of the elements of ``design`` (``HostModel.actuators[name]``)."""
        raise NotImplementedError

    def device_arrays(self, host: dict, arr) -> dict:
        """Device arrays from the host arrays; ``arr(array, dtype=None)`` copies one to the device in
        the model's precision (or as ``dtype``). Called only when the design has elements. The
        differentiable replay calls it too, with an ``arr`` that gives floating-point arrays gradients."""
        raise NotImplementedError

    def rest_controls(self, host: dict) -> np.ndarray:
        """(n,) float64 control of every element when a Control is allocated (default zeros; a passive
        family's controls are placeholders that its forces do not read)."""
        return np.zeros(len(next(iter(host.values()))) if host else 0)

    # ------------------------------------------------------------------ physics
    def eval_forces(self, model, state, control, x, v, f, launch) -> None:
        """Accumulate the elements' forces at (x, v) (W, V) into f; launch nothing without elements.
        ``model.actuators[name]`` holds the family's device arrays, ``model.host`` the host model,
        ``control.values[name]`` / ``control.enabled[name]`` its controls and mask (actuators only).
        In the differentiable replay ``state`` is None: a family's forces read positions, velocities,
        its arrays and its controls only."""
        raise NotImplementedError

    def build(self, model, rest, launch) -> None:
        """Launches that derive the family's device arrays from its parameter arrays and the rest
        positions ``rest`` (V,) vec3 (m), recorded on the differentiable replay's build tape so that
        d objective / d rest positions flows through them (default: nothing derived)."""

    def energy(self, host: dict, x: np.ndarray, controls: np.ndarray, enabled: np.ndarray) -> np.ndarray:
        """(W,) float64 energy in J at positions x (W, V, 3) with controls (W, n) and mask enabled
        (W, n) bool (both unused by a passive family); its negative gradient is ``eval_forces``'s force."""
        raise NotImplementedError

    def stiffness_rows(self, stiff: np.ndarray, damp: np.ndarray, host: dict, inv_m: np.ndarray,
                       inv_sqrt: np.ndarray) -> None:
        """Add the elements' Gershgorin rows of M^-1/2 K M^-1/2 to stiff (W, V) and of the damping rates
        to damp (W, V)."""

    def operator_terms(self, xT: np.ndarray, host: dict):
        """(a, b, axial k, transverse k, directions (3, n)) of the elements' springs for the elastic
        operator at positions xT (3, V), or None (no spring terms)."""
        return None

    def jam_fields(self, model, worlds: int) -> dict:
        """{name: device array} of the per-world jam fields of a new State of ``worlds`` worlds (nothing
        jammed), for a family with ``jams``; each array (W, n) or (k, W, n), its world axis where
        ``copy_worlds`` looks for it."""
        return {}

    def jam(self, model, state, cell: int, world_mask, launch) -> None:
        """Jam the family's elements in cell ``cell`` in the worlds where world_mask (W,) int32 is 1 (an
        element already jammed is left as it is); only for a family with ``jams``."""

    def jam_event(self, model, fields_in: dict, fields_out: dict, now, x, launch) -> None:
        """The differentiable replay's jam event, for a family with ``jams`` and ``differentiable``: launches
        (backward-enabled, writing fresh arrays) that set one world's jam fields ``fields_out`` to
        ``fields_in`` ({name: array}, as ``jam_fields`` of one world), the elements where ``now`` (n,) int32 is
        1 jammed at positions ``x`` (1, V) as ``jam`` jams them; the replay runs their adjoints back to
        the positions and the family's arrays."""
        raise NotImplementedError(f"the force family {self.name!r} jams but has no jam_event for the replay")

    def diagonal_stiffness(self, model, state, diag, launch, control=None) -> None:
        """The static settle's preconditioner part: add each vertex's share of the elements' stiffness
        (N/m, a diagonal estimate) to diag (W, V) at the settle's start (``state``, with ``control``: an
        actuator's stiffness may depend on where its control puts it, e.g. an indenter's contact) (default:
        nothing, for forces much softer than the membrane's; a stiff family adds its own, or the settle
        takes steps too long for it)."""

    def storable_values(self, host: dict) -> dict:
        """{description: array} of the model values a precision must hold (see ``check_storable``)."""
        return {}


#: every passive force family registered (the actuator families are in ``actuators.ACTUATOR_FAMILIES``)
FORCE_FAMILIES = Registry("force family")


def force_families() -> tuple:
    """The registered passive force families, in registration order."""
    return tuple(FORCE_FAMILIES.get(n) for n in FORCE_FAMILIES)


# ---------------------------------------------------------------------------------- actuator families
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
    max_count: int | None = None  # the most elements a design holds (None: no bound)
    count_hint = ""  # what a refusal of too many elements adds, e.g. " (the paper's displays have 4-20)"

    def count_problem(self, n: int) -> str | None:
        """A message when ``n`` elements are more than a design holds (``max_count``), or None."""
        if self.max_count is None or n <= self.max_count:
            return None
        return f"{n} {self.plural}, more than the {self.max_count} a design holds{self.count_hint}; use fewer"

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
