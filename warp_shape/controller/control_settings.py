"""Controller parameters: ControlSettings (rates, gains, deadbands, limits and simulation options)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from ..errors import DesignError
from ..registry import Registry
from ..simulation_settings import SimulationSettings, check_field_types, replace_settings

__all__ = ["ControlSettings", "CONTROL_METHODS", "LAWS", "GRADIENTS"]

#: control methods by name (``ControlSettings.method``; built in: "inverse", "paper"; ``controller.methods``)
CONTROL_METHODS = Registry("control method")
#: control laws by name (``ControlSettings.warm_start``, and each a control method of its own; ``controller.laws``)
LAWS = Registry("control law")
#: how the model-based refinement gets its derivatives (``ControlSettings.inverse_gradient``;
#: ``controller.refine.uses_adjoint``)
GRADIENTS = ("auto", "finite-difference", "adjoint")


@dataclass(frozen=True)
class ControlSettings:
    """Controller parameters (SI). Defaults were chosen by measurement on the Fig. 6 problem and the
    oval/heart design problem (see docs/controller.md). ``simulation``: how the controlled design is
    simulated (integrator, output step dt, precision, substeps, ...)."""

    control_period: int = 10  # simulation steps (of simulation.dt) per control step
    max_steps: int = 300  # control-step limit
    volume_deadband: float = 0.005  # |V - V_t| / V_t
    length_deadband: float = 1e-3  # |L_t - L|, m
    air_rate: float = 0.04  # max |dn| per control step, as a fraction of the rest air amount
    pressure_rate: float = 40e3  # max |dP| per control step, Pa
    air_gain: float = 1.0  # multiplies eq. (11)
    pressure_gain: float = 1.0  # multiplies eq. (12)
    gain_backoff: float = 0.5  # an error that flips sign without halving scales that actuator's gain by this
    min_gain: float = 0.05  # floor of the backed-off gains, relative to air_gain / pressure_gain
    jamming: bool = True  # False: never jam (for path-dependence studies)
    curvature_tolerance: float = 1e-6  # m; a move away from the target smaller than this is noise
    max_stretch: float = 4.0  # mean edge stretch beyond which the target is deemed unreachable
    settle_speed: float = 1e-3  # m/s; at rest when the largest vertex speed is below this (float32 floor ~1e-4)
    max_settle_steps: int = 100  # control steps the controls are held at most for the membrane to come to rest
    method: str = "inverse"  # a name in CONTROL_METHODS: "inverse" (model-based, default) or a law ("paper")
    warm_start: str = "paper"  # the law (a name in LAWS) whose run starts the "inverse" method
    inverse_iterations: int = 6  # Gauss-Newton iteration limit of the model-based refinement
    inverse_tolerance: float = 0.005  # refinement stops when an iteration lowers the objective by less (relative)
    inverse_gradient: str = "auto"  # one of GRADIENTS: the refinement's derivatives (docs/gradients.md)
    inverse_settle_steps: int = 60  # simulation steps each explored world settles before it is measured
    inverse_plans: str = "warm never overinflate1.3 overinflate1.5"  # jam plans tried (controller.plans)
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    workers: int = 0  # processes a batch of targets is sharded over (0: every core, 1: one; controller.shard)

    def __post_init__(self):
        check_field_types(self, "ControlSettings")
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise DesignError(f"ControlSettings.{f.name} must be finite, got {v}")
        CONTROL_METHODS.check(self.method, "ControlSettings.method")
        LAWS.check(self.warm_start, "ControlSettings.warm_start")
        if self.inverse_iterations < 0 or self.inverse_settle_steps < 1 or not self.inverse_tolerance >= 0:
            raise DesignError("ControlSettings needs inverse_iterations >= 0, inverse_settle_steps >= 1 and "
                              "inverse_tolerance >= 0")
        if self.inverse_gradient not in GRADIENTS:
            raise DesignError(f"ControlSettings.inverse_gradient must be one of {', '.join(GRADIENTS)} "
                              f"(auto: the adjoint for many controls), got {self.inverse_gradient!r}")
        if self.control_period < 1 or self.max_steps < 1:
            raise DesignError("ControlSettings needs control_period >= 1 and max_steps >= 1")
        if self.workers < 0:
            raise DesignError(f"ControlSettings.workers must be >= 0 (0: every core, 1: one process), "
                              f"got {self.workers}")
        if self.max_settle_steps < 0:
            raise DesignError(f"ControlSettings.max_settle_steps must be >= 0 (0: never hold to settle), "
                              f"got {self.max_settle_steps}")
        if not isinstance(self.simulation, SimulationSettings):
            raise DesignError(f"ControlSettings.simulation must be a SimulationSettings (warp_shape.simulation_settings), "
                              f"got {type(self.simulation).__name__}")
        for name in ("volume_deadband", "length_deadband", "air_rate", "pressure_rate", "air_gain", "pressure_gain",
                     "gain_backoff", "min_gain", "settle_speed", "max_stretch"):
            if getattr(self, name) <= 0:
                raise DesignError(f"ControlSettings.{name} must be > 0, got {getattr(self, name)}")

    def replace(self, **changes) -> "ControlSettings":
        """A copy with some settings changed; unknown names raise ``DesignError``."""
        return replace_settings(self, changes, "controller")
