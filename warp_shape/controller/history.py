"""The control record: one row per control step and world (columns below) and the membrane frames.

History columns (one row per control step: the state measured at that step, before its update;
``phase`` is the control law applied at that step; ``{i}`` IPAM index, ``{j}`` cell index):
  step, time (s), phase (1 inflation / 2 shape control / 3 hold: controls held while the membrane
  comes to rest), air_mol, pressure_pa (gauge), volume_m3,
  target_volume_m3, ipam{i}_pressure_pa, ipam{i}_length_m, ipam{i}_target_length_m, ipam{i}_force_n
  (axial, + = tension), ipam{i}_strain ((L - L0) / L0), cell{j}_kappa_m, cell{j}_kappa_target_m,
  cell{j}_jammed (0/1), max_speed_m_s (largest vertex speed), objective, pcc, mare_m, mpre_pct.
Another actuator family's columns (``ActuatorFamily.history_columns``) follow the IPAM's.
"""

from __future__ import annotations

import numpy as np

from ..model import HostModel
from ..physics.ipam import IPAM
from .laws import Controls
from .observe import Observation

__all__ = ["HISTORY_COLUMNS", "history_row", "History"]

HISTORY_COLUMNS = ("step", "time", "phase", "air_mol", "pressure_pa", "volume_m3", "target_volume_m3",
                   *IPAM.history_columns, "cell{j}_kappa_m", "cell{j}_kappa_target_m", "cell{j}_jammed",
                   "max_speed_m_s", "objective", "pcc", "mare_m", "mpre_pct")


def history_row(obs: Observation, w: int, phase: int, controls: Controls, host: HostModel) -> dict:
    """World ``w``'s row of the record at this observation (columns in the module docstring)."""
    row = dict(step=obs.step, time=obs.time, phase=int(phase), air_mol=controls.air[w],
               pressure_pa=obs.pressure_abs[w] - host.atmospheric_pressure, volume_m3=obs.volume[w],
               target_volume_m3=obs.target_volume[w])
    for fam in host.actuator_families:  # the IPAM's columns, then every other actuator family's
        part = obs.actuators[fam.name]
        row.update(fam.history_row(part, part["controls"], w, host.actuators[fam.name]))
    for j in range(host.n_cells):
        row[f"cell{j}_kappa_m"] = obs.kappa[w, j]
        row[f"cell{j}_kappa_target_m"] = obs.kappa_target[w, j]
        row[f"cell{j}_jammed"] = int(obs.jammed[w, j])
    row["max_speed_m_s"] = obs.max_speed[w]
    row["objective"] = obs.objective[w]
    row["pcc"] = obs.pcc[w]
    row["mare_m"] = obs.mare[w]
    row["mpre_pct"] = obs.mpre[w]
    return row


class History:
    """Rows and float32 membrane frames of every world, recorded while the world runs."""

    def __init__(self, worlds: int, host: HostModel):
        self.host = host
        self.rows: list[list[dict]] = [[] for _ in range(worlds)]
        self.frames: list[list[np.ndarray]] = [[] for _ in range(worlds)]

    def record(self, obs: Observation, phase: np.ndarray, controls: Controls, done: np.ndarray) -> None:
        """Append this observation's row and frame for every world not yet done."""
        for w in range(len(self.rows)):
            if done[w]:
                continue
            self.rows[w].append(history_row(obs, w, phase[w], controls, self.host))
            self.frames[w].append(obs.positions[w].astype(np.float32))

    def columns(self, w: int) -> dict:
        """World ``w``'s record: column name -> (n_steps,) array."""
        rows = self.rows[w]
        return {k: np.array([r[k] for r in rows]) for k in rows[0]}

    def frame_stack(self, w: int) -> np.ndarray:
        """(n_steps, V, 3) float32 membrane of world ``w`` at every recorded control step."""
        return np.stack(self.frames[w])
