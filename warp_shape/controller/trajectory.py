"""A recorded control sequence being extended: one simulator (one world per target) and its record.

The model-based controller drives its main simulator open loop with planned commands: it ramps the
controls to new values within the rate limits (``air_rate`` of the rest air and ``pressure_rate``
per control step), holds them until the membrane is at rest (largest vertex speed below the
settings' ``settle_speed``, at most ``max_settle_steps`` control steps) and jams cells. Every control step is
recorded as a history row (``controller.history``) with phase ``PHASE_PLANNED``, so the record stays a
sequence a valve controller can replay (``controller.open_loop``). Passive IPAMs are held neutral and
passive cells never jam, as in the control loop.
"""

from __future__ import annotations

import numpy as np

from ..model import HostModel
from .history import History
from .laws import Controls
from .observe import Observation, Observer, ipam_neutral_pressures
from .control_settings import ControlSettings

__all__ = ["Trajectory", "PHASE_PLANNED"]

PHASE_PLANNED = 4  # history phase of the model-based controller's rows (1, 2, 3: the paper's law and its hold)


class Trajectory:
    """The main simulator of one plan and its record, continued control step by control step.

    ``history``: the rows so far (from a warm start, or empty for a start from rest); ``step``: the
    number of the next control step; ``controls``: the controls in force; ``jam_steps``: (W, n_cell)
    the control step at which each cell jammed (-1: never)."""

    def __init__(self, sim, observer: Observer, settings: ControlSettings, history: History, step: int,
                 controls: Controls, jam_steps: np.ndarray, passive_ipams: np.ndarray, passive_cells: np.ndarray):
        self.sim, self.observer, self.settings = sim, observer, settings
        self.host: HostModel = observer.host
        self.history, self.step, self.controls, self.jam_steps = history, int(step), controls, jam_steps
        self.passive_ipams, self.passive_cells = passive_ipams, passive_cells
        self.W = len(controls.air)
        self.last: Observation | None = None
        self.speed = np.full(self.W, np.inf)
        self.settled = np.zeros(self.W, dtype=bool)

    def observe(self, phase: int = PHASE_PLANNED) -> Observation:
        """Observe every world now and record a row for each whose last row is older than now."""
        obs = self.observer.observe(self.sim, self.step, self.controls.air, self.controls.pressures)
        new = np.array([not rows or abs(rows[-1]["time"] - obs.time) > 0.5 * self.sim.dt
                        for rows in self.history.rows])
        self.history.record(obs, np.full(self.W, phase), self.controls, ~new)
        self.last, self.speed = obs, obs.max_speed
        return obs

    def _apply(self, air: np.ndarray, pressures: np.ndarray) -> None:
        """Set the commands for the next control period (passive IPAMs neutral) and step it."""
        if self.host.n_ipams and self.passive_ipams.any():
            neutral = ipam_neutral_pressures(self.last.ipam_lengths, self.host)
            pressures = np.where(self.passive_ipams, neutral, pressures)
        self.controls = Controls(air=np.asarray(air, dtype=np.float64).copy(),
                                 pressures=np.asarray(pressures, dtype=np.float64).reshape(self.W, -1).copy())
        self.sim.air_moles = self.controls.air
        if self.host.n_ipams:
            self.sim.ipam_pressures = self.controls.pressures
        self.sim.step(self.settings.control_period)
        self.step += 1
        self.observe()

    def ramp(self, air: np.ndarray, pressures: np.ndarray) -> None:
        """Move every world's commands to ``air`` (W,) mol and ``pressures`` (W, n_ipam) Pa in equal
        control steps within the rate limits (all of a world's commands arrive together)."""
        if self.last is None:
            self.observe()
        s, host = self.settings, self.host
        a0, p0 = self.controls.air.copy(), self.controls.pressures.copy()
        air = np.asarray(air, dtype=np.float64)
        pressures = np.clip(np.asarray(pressures, dtype=np.float64).reshape(self.W, -1),
                            host.ipam_limits[:, 0], host.ipam_limits[:, 1]) if host.n_ipams else p0
        n_air = np.abs(air - a0) / (s.air_rate * host.rest_air)
        n_p = np.abs(pressures - p0).max(axis=1) / s.pressure_rate if host.n_ipams else np.zeros(self.W)
        n = np.ceil(np.maximum(n_air, n_p) - 1e-9).astype(int)
        for k in range(1, int(n.max(initial=0)) + 1):
            f = np.minimum(k / np.maximum(n, 1), 1.0)
            self._apply(a0 + f * (air - a0), p0 + f[:, None] * (pressures - p0))

    def settle(self) -> None:
        """Hold the commands until every world is at rest (or ``max_settle_steps`` control steps)."""
        if self.last is None:
            self.observe()
        s = self.settings
        for _ in range(s.max_settle_steps):
            if np.all(self.speed < s.settle_speed):
                break
            self._apply(self.controls.air, self.controls.pressures)
        self.settled = self.speed < s.settle_speed

    def jam_all(self) -> None:
        """Jam every cell that is not passive in every world, now (recorded from the next row on)."""
        for w in range(self.W):
            for j in np.flatnonzero(~self.passive_cells[w] & ~np.asarray(self.sim.jammed).reshape(self.W, -1)[w]):
                self.sim.jam(int(j), world=w)
                self.jam_steps[w, j] = self.step

    def states(self) -> list:
        """The current state of every world (``model.WorldRef``, a snapshot on the device)."""
        return self.sim.snapshot()
