"""One design run's shared state (``DesignRun``, what the placement strategies act on) and its
control rounds (``control_round``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..controller import ControlSettings, control_many
from ..design import Design
from .initialize import copy_design
from .placement import PlacementContext
from .selection import Selection
from .settings import DesignSettings

__all__ = ["DesignRun", "control_round", "round_progress"]


@dataclass
class DesignRun:
    """What every part of one design run shares: the problem, the design so far, what was recorded."""

    current: Design  # the design being built (actuator sets are added to it in place)
    targets: list  # centred target meshes
    names: list[str]
    ctx: PlacementContext
    settings: DesignSettings
    control_settings: ControlSettings
    device: str
    progress: object = None  # progress(round, n_rounds, step, max_steps, done, worlds)
    recorder: object = None
    on_round: object = None  # on_round(i, design_i, results_i)
    selection: Selection = None  # what each target's final sequence leaves out
    designs: list = field(default_factory=list)  # the design of each recorded round
    rounds: list = field(default_factory=list)  # the control results of each recorded round
    added: list = field(default_factory=list)  # the record of each actuator set placed
    info: dict = field(default_factory=dict)  # the placement report (DesignResult.placement)
    round_control: str = "paper"  # how the rounds before the last are controlled (DesignSettings.round_control)
    final: bool = False  # the next round is the last

    @property
    def actuators(self) -> int:
        return self.ctx.actuators

    def round_progress(self, i: int):
        """The control progress callback of round ``i``."""
        return round_progress(self.progress, i, self.actuators)


def round_progress(progress, i: int, rounds_total: int):
    def ctl_progress(step, total, done, worlds):
        if progress is not None:
            progress(i, rounds_total, step, total, done, worlds)
    return ctl_progress


def control_round(run: DesignRun, i: int, round_settings: ControlSettings, hold=None) -> list:
    """Round ``i``: the current design controlled to every target (one batch of worlds), the actuators
    each target leaves out held neutral; recorded, appended to ``run.designs`` and ``run.rounds``.
    ``hold``: what the round records instead of the results (``Placement.hold``); the results are
    returned."""
    run.designs.append(copy_design(run.current))
    results = control_many(run.current, run.targets, device=run.device, settings=round_settings,
                           progress=run.round_progress(i), passive_ipams=run.selection.passive_ipams(),
                           passive_cells=run.selection.passive_cells(), recorder=run.recorder,
                           recorder_prefix=f"design/round_{i}", target_names=run.names)
    run.rounds.append(results if hold is None else hold(results))
    if run.recorder is not None:
        run.recorder.log_design_round(i, np.array([r.pcc for r in run.rounds[-1]]), run.names, run.designs[-1])
    if run.on_round is not None:
        run.on_round(i, run.designs[-1], run.rounds[-1])
    return results
