"""ControlResult: the outcome of driving one design to one target, as plain data (writes no files)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..display import Design
from ..mesh import TriMesh
from .control_settings import ControlSettings

__all__ = ["ControlResult", "ScreenResult", "screened"]


@dataclass
class ControlResult:
    """Outcome of driving one design to one target. Files: ``warp_shape.io.outputs``."""

    achieved: TriMesh  # membrane at the end of the control sequence, measured at rest (see ``settled``)
    sampled_target: TriMesh  # the target sampled radially through the achieved vertices
    objective: float  # fit objective: area-weighted RMS of (R - r) / V_t^(1/3) (unitless, 0 = perfect)
    pcc: float
    mare: float  # m
    mpre: float  # %
    volume_error: float  # (V - V_t) / V_t
    ipam_forces: np.ndarray  # (n_ipam,) final axial forces, N (+ = tension)
    ipam_pressures: np.ndarray  # (n_ipam,) final gauge pressures, Pa
    air_moles: float
    jammed: np.ndarray  # (n_cell,) bool
    jam_steps: np.ndarray  # (n_cell,) control step at which each cell jammed, -1 if never
    converged: bool  # at rest, within the deadbands and no actuator saturated
    reason: str  # why the run ended, whether at rest, and which limit stopped it
    saturated: list  # actuators pinned at a limit while their target asks for more, e.g. "ipam 3 at P_max 300 kPa"
    settled: bool  # the final shape is at rest: largest vertex speed below settings.settle_speed
    max_speed: float  # largest vertex speed of the final shape, m/s
    control_steps: int
    history: dict = field(repr=False)  # column name -> (n_steps,) array, see controller.history
    settings: ControlSettings = field(repr=False, default_factory=ControlSettings)
    frames: np.ndarray | None = field(repr=False, default=None)  # (n_steps, V, 3) float32 membrane per control step
    design: Design | None = field(repr=False, default=None)
    target: TriMesh | None = field(repr=False, default=None)
    passive_ipams: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # left out of this run
    passive_cells: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    refinement: dict | None = None  # method "inverse": plan, objectives, stop reason, saturation (controller.inverse)

    @property
    def actuator_summary(self) -> list[dict]:
        """Per IPAM what a builder needs to size it (section IV-C): peak push and pull force (N),
        peak |strain|, and the pressure range used (Pa)."""
        out = []
        for i in range(len(self.ipam_forces)):
            f = self.history[f"ipam{i}_force_n"]
            s = self.history[f"ipam{i}_strain"]
            p = self.history[f"ipam{i}_pressure_pa"]
            out.append(dict(ipam=i, peak_push_n=float(max(0.0, -f.min())), peak_pull_n=float(max(0.0, f.max())),
                            peak_strain=float(np.abs(s).max()), pressure_min_pa=float(p.min()),
                            pressure_max_pa=float(p.max())))
        return out

    def summary(self) -> dict:
        """Fit, final actuator state, convergence and settings as a JSON-ready dict (SI units)."""
        return dict(objective=self.objective, pcc=self.pcc, mare_m=self.mare, mpre_pct=self.mpre,
                    volume_error=self.volume_error, converged=self.converged, saturated=list(self.saturated),
                    settled=self.settled, max_speed_m_s=self.max_speed, reason=self.reason,
                    control_steps=self.control_steps,
                    air_moles=self.air_moles, ipam_forces_n=self.ipam_forces.tolist(),
                    ipam_pressures_pa=self.ipam_pressures.tolist(), jammed=self.jammed.tolist(),
                    jam_steps=self.jam_steps.tolist(), actuators=self.actuator_summary,
                    passive_ipams=self.passive_ipams.tolist(), passive_cells=self.passive_cells.tolist(),
                    refinement=self.refinement, settings=asdict(self.settings))


@dataclass(frozen=True)
class ScreenResult:
    """A control method's estimate of the fit it would reach for one target, without its control
    sequence (``controller.methods.screen_many``): to rank candidates before controlling the best."""

    objective: float  # the fit objective expected (unitless, as ``ControlResult.objective``)
    plan: str | None = None  # method "inverse": the jam plan it would keep
    predicted: bool = False  # True: predicted from the refinement's scratch settles; False: measured at the end of a run
    refinement: dict | None = None  # method "inverse": as ``ControlResult.refinement`` (``objective``: the prediction)


def screened(results) -> list[ScreenResult]:
    """The ``ScreenResult`` of each control result: its measured fit (a method without an estimate of its own)."""
    return [ScreenResult(objective=r.objective, plan=(r.refinement or {}).get("plan"), refinement=r.refinement)
            for r in results]
