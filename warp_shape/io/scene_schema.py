"""The scene as plain data: ``Scene``, its field checks and the one table of its USD attributes.

A scene is a design (or none), target meshes and free-form settings; ``docs/scene_format.md``
describes the file. This module knows no USD library: ``scene_write`` and ``scene_read`` author
and read the attributes listed here (``MATERIAL_ATTRIBUTES``) and those of every actuator family
(``ActuatorFamily.scene_attributes``; the IPAM's are ``IPAM_ATTRIBUTES``), so the writer and the
reader cannot disagree on a name, a type or a field.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from ..force_family import SCENE_NAMESPACE, SceneAttribute
from ..display import Design
from ..errors import SceneError
from ..material import Material
from ..mesh import TriMesh, icosphere, icosphere_like
from ..physics.ipam import IPAM, IPAM_ATTRIBUTES
from ..simulation_settings import SimulationSettings
from ..targets import is_identifier

__all__ = ["Scene", "SceneAttribute", "MATERIAL_ATTRIBUTES", "IPAM_ATTRIBUTES", "SCENE_FORMAT_VERSION",
           "SCENE_EXTENSIONS", "NS", "ROOT_NAME", "MEMBRANE", "IPAMS", "TARGETS", "SETTINGS", "CELL_FAMILY",
           "REST_POINTS", "TARGET_POINTS", "FORMAT_VERSION_ATTRIBUTE", "is_identifier", "check_settings",
           "ipam_attribute_values", "ipam_arguments", "material_attribute_for"]

SCENE_FORMAT_VERSION = 1
SCENE_EXTENSIONS = (".usda", ".usdc", ".usd")
NS = SCENE_NAMESPACE  # namespace of every warp_shape attribute
ROOT_NAME = "Scene"  # the default prim
MEMBRANE, TARGETS, SETTINGS = "Membrane", "Targets", "Settings"  # children of the default prim
IPAMS = IPAM.scene_prim  # the IPAM family's prim; every actuator family has one (ActuatorFamily.scene_prim)
CELL_FAMILY = "jammingCell"  # GeomSubset family of the jamming cells
FORMAT_VERSION_ATTRIBUTE = f"{NS}:formatVersion"
REST_POINTS = f"{NS}:restPoints"  # exact (float64) rest positions of the membrane
TARGET_POINTS = f"{NS}:points"  # exact (float64) vertices of a target

def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(w[:1].upper() + w[1:] for w in rest)


# ---------------------------------------------------------------------------------------------- attribute table
#: The membrane law's fields, read when present (a scene without them holds the paper's springs):
#: the law as a token, mu (written only when set; absent: E / 3) and the Yeoh terms in Pa.
_MEMBRANE_LAW_TYPES = {"membrane": "token", "shear_modulus": "double", "yeoh_c2": "double", "yeoh_c3": "double",
                       "compression": "token"}
#: The Membrane prim: every ``Material`` field as ``custom double warpShape:<camelCaseName>`` (SI), the
#: membrane law's as ``_MEMBRANE_LAW_TYPES`` says (optional).
MATERIAL_ATTRIBUTES = tuple(SceneAttribute(f"{NS}:{_camel(f.name)}", _MEMBRANE_LAW_TYPES.get(f.name, "double"), f.name,
                                           1, f.name not in _MEMBRANE_LAW_TYPES) for f in fields(Material))

def material_attribute_for(message: str) -> str | None:
    """The attribute of the Material field that a ``Material`` error message names, if any."""
    return next((a.name for a in MATERIAL_ATTRIBUTES if f"Material.{a.field} " in message), None)


def ipam_attribute_values(design: Design, attr: SceneAttribute) -> np.ndarray:
    """Values of ``attr`` over every IPAM of ``design``, in IPAM order: (n,) or (n, width) arrays
    (int32 for indices, float64 otherwise)."""
    return IPAM.attribute_values(design, attr)


def ipam_arguments(values: dict, i: int) -> tuple[tuple, dict]:
    """``Design.add_ipam`` arguments of IPAM ``i`` from the required attributes' arrays
    (``{field: array}``, as read): ((face_a, face_b), keyword arguments)."""
    return IPAM.scene_arguments(values, i)


# ---------------------------------------------------------------------------------------------- Scene
@dataclass(eq=False)
class Scene:
    """A design problem or a design: membrane + IPAMs + cells (``design``), targets and settings.

    ``design``: a ``ws.Design`` or None (a scene that only holds targets).
    ``targets``: list of ``TriMesh`` (shipped targets by name: ``scene_registry.resolve_targets``).
    ``target_names``: one identifier per target (default ``target0``, ``target1``, ...); they
    become the prim names under ``Targets``.
    ``settings``: ``{group: {key: value}}`` with identifier groups and keys and bool / int / float /
    str values, e.g. ``{"simulation": {"dt": 1e-3}, "designer": {"actuators": 4}}``.
    """

    design: Design | None = None
    targets: list = field(default_factory=list)
    settings: dict | None = None
    target_names: list | None = None

    def __post_init__(self):
        if self.design is not None and not isinstance(self.design, Design):
            raise SceneError(f"Scene.design must be a ws.Design or None, got {type(self.design).__name__}")
        if isinstance(self.targets, TriMesh):
            self.targets = [self.targets]
        meshes = list(self.targets or [])
        for i, t in enumerate(meshes):
            if isinstance(t, str):
                raise SceneError(f"Scene.targets[{i}] is the name {t!r}: a Scene holds meshes; resolve target "
                                 f"names with warp_shape.io.scene_registry.resolve_targets (or ws.target)")
            if not isinstance(t, TriMesh):
                raise SceneError(f"Scene.targets[{i}] must be a TriMesh, got {type(t).__name__}")
        names = [f"target{i}" for i in range(len(meshes))] if self.target_names is None \
            else [str(n) for n in self.target_names]
        if len(names) != len(meshes):
            raise SceneError(f"Scene.target_names has {len(names)} names for {len(meshes)} targets")
        for n in names:
            if not is_identifier(n):
                raise SceneError(f"target name {n!r} is not an identifier (letters, digits, _; not starting "
                                 f"with a digit); it becomes a USD prim name")
        if len(set(names)) != len(names):
            raise SceneError(f"target names must be unique, got {names}")
        self.targets = meshes
        self.target_names = names
        self.settings = check_settings(self.settings)

    def base_mesh(self, subdivisions: int | None = None) -> TriMesh:
        """The membrane a design of this problem starts from: the design's rest shape, or for a scene of
        targets only the default sphere (642 vertices, radius 35 mm); with ``subdivisions``, an
        icosphere of that many subdivisions whose sphere holds that mesh's volume (m^3)."""
        base = self.design.rest if self.design is not None else icosphere(3, 0.035)
        return base if subdivisions is None else icosphere_like(base, subdivisions)

    def target(self, name: str) -> TriMesh:
        """The target called ``name``."""
        try:
            return self.targets[self.target_names.index(name)]
        except ValueError:
            raise SceneError(f"scene has no target {name!r}; it has {self.target_names}") from None

    @property
    def simulation_settings(self) -> SimulationSettings:
        """The defaults of ``SimulationSettings`` updated by the scene's ``settings["simulation"]``."""
        return SimulationSettings.from_dict(self.settings.get("simulation", {}))

    def __repr__(self) -> str:
        return (f"Scene(design={self.design!r}, targets={self.target_names}, "
                f"settings={sorted(self.settings)})")


def _setting_value(group: str, key: str, value):
    """``value`` as the Python type it is stored as (bool, int, float or str)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        value = int(value)
        if not -(2**63) <= value < 2**63:
            raise SceneError(f"settings[{group!r}][{key!r}] = {value} does not fit in 64 bits")
        return value
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, str):
        return value
    raise SceneError(f"settings[{group!r}][{key!r}] must be a bool, int, float or str, got {type(value).__name__}")


def check_settings(settings) -> dict:
    """Scene settings checked and normalised: ``{group: {key: bool | int | float | str}}``."""
    if settings is None:
        return {}
    if not isinstance(settings, dict):
        raise SceneError(f"Scene.settings must be a dict {{group: {{key: value}}}}, got {type(settings).__name__}")
    out = {}
    for group, entries in settings.items():
        if not is_identifier(group):
            raise SceneError(f"settings group {group!r} must be an identifier (it becomes part of an attribute name)")
        if not isinstance(entries, dict):
            raise SceneError(f"settings[{group!r}] must be a dict of key -> bool/int/float/str, "
                             f"got {type(entries).__name__}")
        g = {}
        for key, value in entries.items():
            if not is_identifier(key):
                raise SceneError(f"settings[{group!r}] key {key!r} must be an identifier")
            g[key] = _setting_value(group, key, value)
        out[group] = g
    return out
