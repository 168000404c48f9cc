"""RunSettings: every option of one run (simulation, control, design, material), built once.

Every command (``design``, ``control``, ``export``, ``sweep``) builds one ``RunSettings`` from its
scene's settings groups and its flags (``RunSettings.from_groups``) and passes it down whole; a
design's ``design.usda`` stores it (``groups``), so re-controlling a saved design runs with the
settings it was designed with. The groups are those of docs/scene_format.md: ``simulation``
(``SimulationSettings``), ``controller`` (``ControlSettings``; the per-target actuator passive_sets a
design stores there is read by ``passive_from_settings``) and ``designer`` (``DesignSettings`` and
``actuators``). The material is the design's own (``Design.material``); ``material`` here is the one
a design run gives its new design.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..controller import ControlSettings
from ..errors import DesignError
from ..material import Material
from ..simulation_settings import SimulationSettings
from .passive import PASSIVE_PREFIXES
from .design_settings import DEFAULT_ACTUATORS, DesignSettings

__all__ = ["RunSettings", "designer_fields"]
_PAIR_FIELDS = ("ipam_pressure_limits",)  # tuples, stored as "lo hi" strings (scene settings are scalars)


def designer_fields(values: dict) -> dict:
    """A scene's ``designer`` values as ``DesignSettings`` keywords (pairs stored as strings parsed)."""
    out = dict(values)
    for name in _PAIR_FIELDS:
        if isinstance(out.get(name), str):
            try:
                out[name] = tuple(float(v) for v in out[name].split())
            except ValueError:
                raise DesignError(f"designer setting {name} must be two numbers 'P_min P_max' in Pa, "
                                  f"got {out[name]!r}") from None
    return out


def _stored(value):
    """A settings value as a scene stores it (bool, int, float or str)."""
    if isinstance(value, tuple):
        return " ".join(repr(float(v)) for v in value)
    return value


@dataclass(frozen=True)
class RunSettings:
    """Every option of one run (module docstring)."""

    control: ControlSettings = field(default_factory=ControlSettings)  # with the simulation settings inside
    designer: DesignSettings = field(default_factory=DesignSettings)
    actuators: int = DEFAULT_ACTUATORS  # IPAMs a design places
    material: Material | None = None  # a new design's material (None: the default Material)

    def __post_init__(self):
        for name, kind in (("control", ControlSettings), ("designer", DesignSettings)):
            if not isinstance(getattr(self, name), kind):
                raise DesignError(f"RunSettings.{name} must be a {kind.__name__}, got "
                                  f"{type(getattr(self, name)).__name__}")
        a = self.actuators
        if isinstance(a, bool) or not isinstance(a, int) or a < 1:
            raise DesignError(f"the number of actuators must be a whole number >= 1, got {a!r}")
        if self.material is not None and not isinstance(self.material, Material):
            raise DesignError(f"RunSettings.material must be a ws.Material, got {type(self.material).__name__}")

    @property
    def simulation(self) -> SimulationSettings:
        return self.control.simulation

    @classmethod
    def from_groups(cls, groups: dict | None = None, *, simulation: dict | None = None,
                    controller: dict | None = None, designer: dict | None = None,
                    material: Material | None = None) -> "RunSettings":
        """The settings of a scene's groups (``{group: {key: value}}``; other groups are ignored), then
        the overrides of each group (a command's flags; None values are ignored). Unknown keys and bad
        values are errors naming the group and the key."""
        groups = groups or {}
        pick = lambda over: {k: v for k, v in (over or {}).items() if v is not None}  # noqa: E731
        sim = SimulationSettings.from_dict(groups.get("simulation")).replace(**pick(simulation))
        ctl = {k: v for k, v in groups.get("controller", {}).items() if not k.startswith(PASSIVE_PREFIXES)}
        ctl.update(pick(controller))
        control = ControlSettings().replace(simulation=sim, **ctl)
        des = dict(groups.get("designer", {}))
        des.update(pick(designer))
        actuators = des.pop("actuators", DEFAULT_ACTUATORS)
        return cls(control=control, designer=DesignSettings().replace(**designer_fields(des)),
                   actuators=actuators, material=material)

    def groups(self) -> dict:
        """The settings as scene groups (``{group: {key: value}}``), as ``from_groups`` reads them. The
        worker count is the machine's, not the design's: it is not stored."""
        ctl = {f.name: getattr(self.control, f.name) for f in dataclasses.fields(self.control)
               if f.name not in ("simulation", "workers")}
        des = {f.name: _stored(getattr(self.designer, f.name)) for f in dataclasses.fields(self.designer)
               if f.name != "workers"}
        return {"simulation": self.simulation.to_dict(),
                "controller": {k: v for k, v in ctl.items() if v is not None},
                "designer": {"actuators": self.actuators, **des}}
