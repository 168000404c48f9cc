"""One design run's shared state: ``DesignRun``, what the placement strategies read and the design
loop changes (applying the placements' decisions, ``designer.loop.apply_decision``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..controller import ControlSettings
from ..controller.problem import Problem
from ..display import Design
from .placement import PlacementContext
from .passive import PassiveSets
from .design_settings import DesignSettings

__all__ = ["DesignRun"]


@dataclass
class DesignRun:
    """What every part of one design run shares: the problem, the design so far, what was recorded."""

    current: Design  # the design being built (actuator sets are added to it in place)
    problem: Problem  # the run's targets (centred), names, volumes, sampler and checks, built once
    ctx: PlacementContext
    settings: DesignSettings
    control_settings: ControlSettings
    device: str
    progress: object = None  # progress(round, n_rounds, step, max_steps, done, worlds)
    recorder: object = None
    on_round: object = None  # on_round(i, design_i, results_i)
    passive_sets: PassiveSets = None  # what each target's final sequence leaves out
    designs: list = field(default_factory=list)  # the design of each recorded round
    rounds: list = field(default_factory=list)  # the control results of each recorded round
    added: list = field(default_factory=list)  # the record of each actuator set placed
    info: dict = field(default_factory=dict)  # the placement report (DesignResult.placement)
    round_control: str = "law"  # how the rounds before the last are controlled (DesignSettings.round_control)
    final: bool = False  # the next round is the last

    @property
    def targets(self) -> Problem:
        """The run's problem, read as its sequence of centred target meshes."""
        return self.problem

    @property
    def names(self) -> list[str]:
        return self.problem.names

    @property
    def actuators(self) -> int:
        return self.ctx.actuators

    def round_progress(self, i: int):
        """The control progress callback of round ``i``: ``progress(i, actuators, step, total, done, worlds)``."""
        def ctl_progress(step, total, done, worlds):
            if self.progress is not None:
                self.progress(i, self.actuators, step, total, done, worlds)
        return ctl_progress
