"""DesignResult: everything a design run produced, as plain data (the Markdown report is in io.report)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..controller import ControlResult, ControlSettings
from ..display import Design
from .passive import passive_to_settings
from .design_settings import DesignSettings

__all__ = ["DesignResult"]


@dataclass
class DesignResult:
    """Everything the designer produced."""

    design: Design  # the final design
    designs: list  # D_0 .. D_p
    rounds: list  # rounds[i][j]: ControlResult of design D_i driven to target j
    pcc_by_round: np.ndarray  # (p + 1, n_targets)
    target_names: list
    targets: list  # centred targets (TriMesh)
    added: list = field(default_factory=list)  # per added actuator: round, target, faces, errors
    passive_ipams: list = field(default_factory=list)  # per target: IPAMs left out of its control sequence
    passive_cells: list = field(default_factory=list)  # per target: cells left out of its control sequence
    settings: DesignSettings = field(default_factory=DesignSettings)
    control_settings: ControlSettings = field(default_factory=ControlSettings)
    placement: dict = field(default_factory=dict)  # method, K, start PCC, bad start, every candidate's scores
    codesign: dict = field(default_factory=dict)  # what co-design did (designer.codesign.CodesignRecord.as_dict)

    @property
    def objective_by_round(self) -> np.ndarray:
        """(rounds, n_targets) fit objective of every target after every round."""
        return np.array([[r.objective for r in rs] for rs in self.rounds])

    @property
    def results(self) -> list[ControlResult]:
        """One control result per target for the final design."""
        return self.rounds[-1]

    def passive_settings(self) -> dict:
        """Controller settings recording which actuators each target's sequence leaves out (flat
        string entries, as scene settings require): ``passive_ipams_<target>`` = "2 3"."""
        return passive_to_settings(self.target_names, self.passive_ipams, self.passive_cells)

    def report(self) -> dict:
        """The design outcome as a JSON-ready dict: PCC by round, actuators added, final fit, settings."""
        fin = self.results
        return dict(
            targets=self.target_names,
            actuators=self.design.n_ipams, cells=self.design.n_cells,
            vertices=self.design.rest.n_vertices, membrane=self.design.material.membrane_summary(),
            pcc_by_round=self.pcc_by_round.tolist(),
            objective_by_round=self.objective_by_round.tolist(),
            mare_by_round=[[r.mare for r in rs] for rs in self.rounds],
            mpre_by_round=[[r.mpre for r in rs] for rs in self.rounds],
            placement=self.placement, codesign=self.codesign,
            final={name: r.summary() for name, r in zip(self.target_names, fin)},
            added=self.added,
            settings=dict(designer=asdict(self.settings), controller=asdict(self.control_settings)),
        )
