"""Simulation settings: one set of options shared by the Simulator, scenes and the controller."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from .errors import DesignError

__all__ = ["SimulationSettings", "replace_settings", "INTEGRATOR_NAMES", "PRECISION_NAMES", "LAUNCH_MODES",
           "DEFAULT_MAX_SUBSTEPS"]

INTEGRATOR_NAMES = ("rk4", "semi_implicit")
INTEGRATOR_ALIASES = {"euler": "semi_implicit", "semi_implicit_euler": "semi_implicit",
                      "symplectic_euler": "semi_implicit"}
PRECISION_NAMES = ("float32", "float64")
BENDING_NAMES = ("exact", "paper")
LAUNCH_MODES = ("graph", "record", "direct")
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
    """

    integrator: str = "rk4"
    dt: float = 1e-3
    precision: str = "float32"
    bending: str = "exact"
    substeps: int | None = None
    launch_mode: str = "graph"
    reestimate_every: int = 1000
    max_substeps: int = DEFAULT_MAX_SUBSTEPS

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
        for name in ("substeps", "reestimate_every", "max_substeps"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, int(value))

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
