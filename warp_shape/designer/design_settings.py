"""Designer parameters: DesignSettings (placement, cell radius, initial volume, end separation, IPAM properties)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ..display import DEFAULT_IPAM_AREA, DEFAULT_IPAM_DAMPING, DEFAULT_IPAM_PRESSURE_LIMITS, DEFAULT_IPAM_STIFFNESS
from ..errors import DesignError
from ..registry import Registry
from ..simulation_settings import check_field_types, replace_settings

__all__ = ["DesignSettings", "ROUND_CONTROLS", "round_control_settings", "PLACEMENTS", "DEFAULT_ACTUATORS",
           "CODESIGN_MODES"]

#: what co-design optimises after placement: nothing, the rest shape, or the rest shape and the IPAM sizes
CODESIGN_MODES = ("off", "rest", "rest+ipams")

DEFAULT_ACTUATORS = 4  # the IPAMs a design places unless the scene or a flag says otherwise

#: placements by name (``DesignSettings.placement``; built in: "simulated", "paper", "greedy";
#: ``designer.placement``; docs/placement.md compares them)
PLACEMENTS = Registry("placement")

#: How the designer controls the rounds before the last (the last round always uses the control
#: settings as given, so that re-controlling the saved design reproduces its sequences):
#: "law": the law that warm-starts the design's controller alone (``ControlSettings.warm_start``, the
#: paper's by default: Algorithm 1 as published; the placement sees its errors; fastest);
#: "quick": model-based control with the warm start's jam times only and at most two refinement steps;
#: "full": the control settings as given, in every round.
ROUND_CONTROLS = ("law", "quick", "full")
ROUND_CONTROL_ALIASES = {"paper": "law"}  # the former name of "law"


def round_control_settings(control_settings, round_control: str):
    """The controller settings of a round before the last (see ``ROUND_CONTROLS``)."""
    if round_control == "law":  # the law that starts the design's controller (the paper's, by default)
        return control_settings.replace(method=control_settings.warm_start)
    if round_control == "quick" and control_settings.method == "inverse":
        return control_settings.replace(inverse_plans="warm",
                                        inverse_iterations=min(2, control_settings.inverse_iterations))
    return control_settings


@dataclass(frozen=True)
class DesignSettings:
    """Designer parameters (SI)."""

    cell_radius: float = 0.012  # m, jamming-cell radius around each IPAM end (rest-shape distance)
    volume_scale: float = 0.8  # rest volume / smallest target volume (multi-target initialisation)
    min_angle_deg: float = 120.0  # the two IPAM ends are at least this far apart seen from the origin
    initialize: bool = True  # False: keep the given rest shape (single-target mode)
    placement: str = "simulated"  # a name in PLACEMENTS
    candidates: int = 4  # K: "simulated": holds tried per target per refinement round; "greedy": sets per round
    min_gain: float = 0.005  # a candidate must lower an objective by this fraction ("simulated", "greedy": else stop)
    refine_rounds: int = 5  # "simulated": refinement rounds at most after the last round (0: none)
    screen_first: int = 2  # "simulated": holds per target screened first; the rest only where those gain (0: all K)
    ipam_stiffness: float = DEFAULT_IPAM_STIFFNESS  # N/m of every added IPAM
    ipam_area: float = DEFAULT_IPAM_AREA  # m^2
    ipam_damping: float = DEFAULT_IPAM_DAMPING  # N s/m
    ipam_pressure_limits: tuple = DEFAULT_IPAM_PRESSURE_LIMITS  # Pa gauge
    round_control: str = "law"  # control of the rounds before the last: "law", "quick" or "full" (ROUND_CONTROLS)
    codesign: str = "rest+ipams"  # after placement: "off", "rest" or "rest+ipams" (CODESIGN_MODES, docs/gradients.md)
    codesign_steps: int = 8  # co-design's descent steps at most per round
    codesign_rounds: int = 2  # co-design's rounds at most (descent steps, then a re-control of every target; a
    # round whose steps stopped gaining (CodesignSettings.min_gain) is the last)
    workers: int = 0  # processes the run's control jobs are sharded over (0: every core, 1: one; controller.shard)

    def __post_init__(self):
        check_field_types(self, "DesignSettings")
        if not (self.cell_radius > 0 and math.isfinite(self.cell_radius)):
            raise DesignError(f"cell_radius must be a positive length in m, got {self.cell_radius}")
        if not 0 < self.volume_scale <= 1:
            raise DesignError(f"volume_scale must be in (0, 1], got {self.volume_scale}")
        object.__setattr__(self, "round_control", ROUND_CONTROL_ALIASES.get(self.round_control, self.round_control))
        if self.round_control not in ROUND_CONTROLS:
            raise DesignError(f"round_control must be one of {list(ROUND_CONTROLS)}, got {self.round_control!r}")
        PLACEMENTS.check(self.placement, "DesignSettings.placement")
        if self.codesign not in CODESIGN_MODES:
            raise DesignError(f"codesign must be one of {list(CODESIGN_MODES)}, got {self.codesign!r}")
        if isinstance(self.codesign_steps, bool) or not isinstance(self.codesign_steps, numbers.Integral) \
                or not 0 <= self.codesign_steps <= 100:
            raise DesignError(f"codesign_steps must be a whole number in 0..100, got {self.codesign_steps!r}")
        if isinstance(self.codesign_rounds, bool) or not isinstance(self.codesign_rounds, numbers.Integral) \
                or not 1 <= self.codesign_rounds <= 20:
            raise DesignError(f"codesign_rounds must be a whole number in 1..20, got {self.codesign_rounds!r}")
        if self.workers < 0:
            raise DesignError(f"workers must be >= 0 (0: every core, 1: one process), got {self.workers}")
        whole = isinstance(self.candidates, numbers.Integral) and not isinstance(self.candidates, bool)
        if not whole or self.candidates < 1:
            raise DesignError(f"candidates must be a whole number >= 1 (candidate actuator sets per round), got "
                              f"{self.candidates!r}")
        if isinstance(self.refine_rounds, bool) or not isinstance(self.refine_rounds, numbers.Integral) \
                or self.refine_rounds < 0:
            raise DesignError(f"refine_rounds must be a whole number >= 0 (refinement rounds of simulated placement), "
                              f"got {self.refine_rounds!r}")
        if isinstance(self.screen_first, bool) or not isinstance(self.screen_first, numbers.Integral) \
                or self.screen_first < 0:
            raise DesignError(f"screen_first must be a whole number >= 0 (holds screened first per target; 0: all "
                              f"K at once), got {self.screen_first!r}")
        if not (0 <= self.min_gain < 1):
            raise DesignError(f"min_gain must be a relative gain in [0, 1) (e.g. 0.005), got {self.min_gain}")
        if not 0 < self.min_angle_deg < 180:
            raise DesignError(f"min_angle_deg must be in (0, 180), got {self.min_angle_deg}")
        self._check_ipam_properties()

    def _check_ipam_properties(self) -> None:
        """The added IPAMs' properties, checked before any round runs (as ``Design.add_ipam`` would)."""
        for name in ("ipam_stiffness", "ipam_area", "ipam_damping"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v < 0 or (v == 0 and name != "ipam_damping"):
                raise DesignError(f"{name} must be a finite number {'>= 0' if name == 'ipam_damping' else '> 0'}, "
                                  f"got {v!r}")
        try:
            lo, hi = (float(p) for p in self.ipam_pressure_limits)
        except (TypeError, ValueError):
            raise DesignError(f"ipam_pressure_limits must be a pair (P_min, P_max) in Pa gauge, "
                              f"got {self.ipam_pressure_limits!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise DesignError(f"ipam_pressure_limits must be finite with P_min <= P_max, got ({lo}, {hi})")

    def replace(self, **changes) -> "DesignSettings":
        """A copy with some settings changed; unknown names raise ``DesignError``."""
        return replace_settings(self, changes, "designer")
