"""Simulation settings: one set of options shared by the Simulator, scenes and the controller."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from .errors import DesignError

__all__ = ["SimulationSettings", "replace_settings", "check_field_types", "settings_or_default", "INTEGRATOR_NAMES", "PRECISION_NAMES", "LAUNCH_MODES",
           "DEFAULT_MAX_SUBSTEPS", "SETTLE_NAMES"]

INTEGRATOR_NAMES = ("rk4", "semi_implicit")
INTEGRATOR_ALIASES = {"euler": "semi_implicit", "semi_implicit_euler": "semi_implicit",
                      "symplectic_euler": "semi_implicit"}
PRECISION_NAMES = ("float32", "float64")
BENDING_NAMES = ("exact", "paper")
LAUNCH_MODES = ("graph", "record", "direct")
SETTLE_NAMES = ("dynamic", "static")
DEFAULT_MAX_SUBSTEPS = 10_000


def replace_settings(settings, changes: dict, what: str):
    """A copy of a settings dataclass with ``changes`` applied; unknown names are an error."""
    known = {f.name for f in fields(settings)}
    unknown = sorted(str(k) for k in set(changes) - known)
    if unknown:
        raise DesignError(f"unknown {what} setting(s) {unknown}; known: {sorted(known)}")
    d = {f.name: getattr(settings, f.name) for f in fields(settings)}
    d.update(changes)
    return type(settings)(**d)


def settings_or_default(value, cls, name: str):
    """``value`` when it is a ``cls``, ``cls()`` for None; anything else (a dict, say) raises ``DesignError``
    naming the keyword ``name`` and how to build one."""
    if value is None:
        return cls()
    if not isinstance(value, cls):
        raise DesignError(f"{name} must be a {cls.__name__} or None, got {type(value).__name__}; build one with "
                          f"{cls.__name__}(**{{...}}) (or pass the settings as keywords)")
    return value


def check_field_types(settings, owner: str) -> None:
    """Check (and normalise) every field of a settings dataclass by its annotation: a ``bool`` field takes
    True / False only (``"no"`` would be truthy), an ``int`` field a whole number (2.0 becomes 2; 1.5, a
    bool or a string are refused, not truncated), a ``float`` field a finite real number, a ``str`` field
    text; ``X | None`` also takes None. Other annotations are left to the class. Raises ``DesignError``
    naming ``owner.field``, the value and what it must be."""
    for f in fields(settings):
        kind = str(f.type).replace(" ", "")
        value = getattr(settings, f.name)
        if kind.endswith("|None"):
            if value is None:
                continue
            kind = kind[:-5]
        checked = _typed_value(kind, value)
        if checked is _WRONG:
            what = {"bool": "True or False", "int": "a whole number", "float": "a finite number",
                    "str": "a string"}[kind]
            raise DesignError(f"{owner}.{f.name} must be {what}, got {value!r} ({type(value).__name__})")
        if checked is not _UNCHECKED:
            object.__setattr__(settings, f.name, checked)


_WRONG, _UNCHECKED = object(), object()


def _typed_value(kind: str, value):
    """``value`` as a ``kind`` ("bool", "int", "float", "str"); ``_WRONG`` where it is not one,
    ``_UNCHECKED`` for other annotations."""
    is_bool = isinstance(value, (bool, np.bool_))
    if kind == "bool":
        return bool(value) if is_bool else _WRONG
    if kind == "str":
        return value if isinstance(value, str) else _WRONG
    if kind not in ("int", "float"):
        return _UNCHECKED
    if is_bool or not isinstance(value, (int, float, np.integer, np.floating)):
        return _WRONG
    if isinstance(value, (int, np.integer)):
        return int(value) if kind == "int" else (float(value) if abs(value) < 2**1023 else _WRONG)
    if not math.isfinite(value):
        return _WRONG
    if kind == "float":
        return float(str(value)) if isinstance(value, np.floating) else float(value)
    return int(value) if float(value).is_integer() else _WRONG


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


@dataclass(frozen=True)
class SimulationSettings:
    """How a design is simulated (SI units).

    integrator: ``"rk4"`` (the paper's reference) or ``"semi_implicit"`` (symplectic Euler; aliases
        ``euler``, ``symplectic_euler``). dt: output (control) step in s; the solver splits it into
        internal steps within its stable-step estimate. precision: ``"float32"`` or ``"float64"``.
    bending: ``"exact"`` (the energy's gradient) or ``"paper"`` (eq. 9).
    substeps: None (automatic from the stable-step estimate) or a fixed count >= 1.
    launch_mode: ``"graph"`` (captured and replayed), ``"record"`` (recorded launches) or ``"direct"``.
    reestimate_every: internal steps between periodic re-estimates of the stable step (0: never).
    max_substeps: most internal steps one output step may take (default 10000, a few seconds of host
        work on a 642-vertex membrane); an automatic split beyond it raises ``StabilityError`` naming the
        material or state value that made the stable step so small.
    settle: how a run that only holds its controls until rest finds the rest state: ``"dynamic"`` (the
        damped dynamics, the reference) or ``"static"`` (the default: the equilibrium of the potential energy,
        ``Simulator.settle_static``; docs/equilibria.md says where it is used and where not).
    """

    integrator: str = "rk4"
    dt: float = 1e-3
    precision: str = "float32"
    bending: str = "exact"
    substeps: int | None = None
    launch_mode: str = "graph"
    reestimate_every: int = 1000
    max_substeps: int = DEFAULT_MAX_SUBSTEPS
    settle: str = "static"

    def __post_init__(self):
        key = str(self.integrator).lower().replace("-", "_") if isinstance(self.integrator, str) else None
        key = INTEGRATOR_ALIASES.get(key, key)
        if key not in INTEGRATOR_NAMES:
            raise DesignError(f"unknown integrator {self.integrator!r}; choose one of {list(INTEGRATOR_NAMES)}")
        object.__setattr__(self, "integrator", key)
        dt = self.dt
        if isinstance(dt, (bool, np.bool_)) or not isinstance(dt, (int, float, np.integer, np.floating)) \
                or not math.isfinite(dt) or dt <= 0:
            raise DesignError(f"dt must be a positive number of seconds, got {dt!r}")
        # a float32 such as np.float32(1e-3) means the decimal it prints as, not its binary neighbour
        object.__setattr__(self, "dt", float(str(dt)) if isinstance(dt, np.floating) else float(dt))
        if not isinstance(self.precision, str) or self.precision not in PRECISION_NAMES:
            raise DesignError(f"precision must be one of {list(PRECISION_NAMES)}, got {self.precision!r}")
        if not isinstance(self.bending, str) or self.bending not in BENDING_NAMES:
            raise DesignError(f"bending must be 'exact' or 'paper', got {self.bending!r}")
        if self.substeps is not None and (not _is_int(self.substeps) or self.substeps < 1):
            raise DesignError(f"substeps must be None (automatic) or an integer >= 1, got {self.substeps!r}")
        if not isinstance(self.launch_mode, str) or self.launch_mode not in LAUNCH_MODES:
            raise DesignError(f"launch_mode must be one of {LAUNCH_MODES}, got {self.launch_mode!r}")
        if not _is_int(self.reestimate_every) or self.reestimate_every < 0:
            raise DesignError(f"reestimate_every must be an integer >= 0 (0: never), got {self.reestimate_every!r}")
        if not _is_int(self.max_substeps) or self.max_substeps < 1:
            raise DesignError(f"max_substeps must be an integer >= 1 (internal steps per output step), "
                              f"got {self.max_substeps!r}")
        if self.substeps is not None and self.substeps > self.max_substeps:
            raise DesignError(f"substeps = {self.substeps} is more than max_substeps = {self.max_substeps}; use fewer "
                              f"substeps (a longer internal step) or raise max_substeps")
        if not isinstance(self.settle, str) or self.settle not in SETTLE_NAMES:
            raise DesignError(f"settle must be one of {list(SETTLE_NAMES)}, got {self.settle!r}")
        check_field_types(self, "SimulationSettings")

    def replace(self, **changes) -> "SimulationSettings":
        """A copy with some settings changed; unknown names raise ``DesignError``."""
        return replace_settings(self, changes, "simulation")

    def to_dict(self) -> dict:
        """Every setting by name (None values left out, as scene settings require)."""
        return {k: v for k, v in asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, d: dict | None) -> "SimulationSettings":
        """Settings from ``to_dict`` output (or a scene's ``simulation`` group); unknown keys raise."""
        if d is not None and not isinstance(d, dict):
            raise DesignError(f"simulation settings must be a dict {{name: value}}, got {type(d).__name__}")
        return replace_settings(cls(), dict(d or {}), "simulation")
