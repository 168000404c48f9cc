"""Observations for a calibration: a scan and the control state the device held when it was taken.

The state comes from a control result (a time into its recorded sequence, or its end), from rows of a
valve schedule, or is given directly (``ControlState``: air, IPAM pressures, jammed cells). Every
state becomes a ``Sequence``: rows of (time, air, IPAM pressures, jammed cells) replayed open loop
from rest, as ``ws.replay`` does, then held until the membrane is at rest, when a lab scans it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..controller.open_loop import control_schedule
from ..controller.result import ControlResult
from ..display import Design
from ..errors import DesignError, ShapeError
from ..model import host_model
from ..scan import LENGTH_UNITS, check_scan_spread, length_unit_of, load_scan
from ..simulation_settings import SimulationSettings

__all__ = ["ControlState", "Sequence", "ScanObservation", "RAMP_S", "MIN_SCAN_POINTS"]

#: seconds over which a directly given state is ramped from rest (then held)
RAMP_S = 0.1
#: fewest points a scan needs
MIN_SCAN_POINTS = 50


@dataclass(frozen=True)
class ControlState:
    """A control state given directly: chamber air ``air_moles`` (mol), ``ipam_pressures`` (n_ipam,) Pa
    gauge, ``jammed`` (cell indices jammed once the ramp has reached the state). From rest the controls
    ramp linearly to the state over ``ramp_s`` seconds; the cells jam there; the state is then held."""

    air_moles: float
    ipam_pressures: tuple = ()
    jammed: tuple = ()
    ramp_s: float = RAMP_S


@dataclass
class Sequence:
    """A replayable control sequence: ``times`` (n,) s from 0, ``air`` (n,) mol, ``pressures``
    (n, n_ipam) Pa, ``jammed`` (n, n_cell) bool (jammed at or before the row), the actuators it leaves
    out (``passive_ipams``, ``passive_cells``) and how it was simulated (``simulation``)."""

    times: np.ndarray
    air: np.ndarray
    pressures: np.ndarray
    jammed: np.ndarray
    passive_ipams: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    passive_cells: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    simulation: SimulationSettings = field(default_factory=SimulationSettings)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def pressure_range(self) -> np.ndarray:
        """(n_ipam,) the largest change of each IPAM's pressure over the sequence, Pa."""
        if self.pressures.shape[1] == 0:
            return np.zeros(0)
        return np.ptp(np.vstack([np.zeros((1, self.pressures.shape[1])), self.pressures]), axis=0)


def result_sequence(result: ControlResult, time: float | None) -> Sequence:
    """The rows of ``result``'s history up to ``time`` s (None: all of them)."""
    dt = result.settings.simulation.dt
    steps, air, p, jam = control_schedule(result, dt)
    t = steps * dt
    if time is not None:
        time = float(time)
        if not (np.isfinite(time) and 0.0 <= time <= t[-1] + 1e-9):
            raise DesignError(f"observation time {time!r} s is outside the result's sequence (0 to {t[-1]:.3f} s)")
        last = int(np.searchsorted(t, time + 1e-9)) - 1
        t, air, p, jam = t[: last + 1], air[: last + 1], p[: last + 1], jam[: last + 1]
    return Sequence(t, air, p, jam, np.asarray(result.passive_ipams, np.int64),
                    np.asarray(result.passive_cells, np.int64), result.settings.simulation)


def state_sequence(state: ControlState, design: Design, simulation: SimulationSettings) -> Sequence:
    """A ramp from rest to ``state`` over ``state.ramp_s`` (rows every control period), cells jammed at its end."""
    rest_air = host_model(design).rest_air
    p = np.asarray(state.ipam_pressures, dtype=np.float64).reshape(-1)
    jam = np.zeros(design.n_cells, bool)
    jam[np.asarray(state.jammed, dtype=np.int64)] = True
    n = max(2, int(round(state.ramp_s / (10 * simulation.dt))) + 1)
    f = np.linspace(0.0, 1.0, n)
    times = f * state.ramp_s
    air = rest_air + f * (float(state.air_moles) - rest_air)
    jammed = np.zeros((n + 1, design.n_cells), bool)
    jammed[-1] = jam
    times = np.append(times, state.ramp_s + 10 * simulation.dt)
    air = np.append(air, air[-1])
    pressures = np.vstack([f[:, None] * p[None, :], p[None, :]])
    return Sequence(times, air, pressures, jammed, simulation=simulation)


def check_state(state: ControlState, design: Design, what: str) -> None:
    """A clear one-line ``DesignError`` where ``state`` does not fit ``design``."""
    p = np.asarray(state.ipam_pressures, dtype=np.float64).reshape(-1)
    if p.size != design.n_ipams:
        raise DesignError(f"{what}: the control state gives {p.size} IPAM pressure(s) but the design has "
                          f"{design.n_ipams} IPAMs; give one pressure (Pa gauge) per IPAM")
    if not np.all(np.isfinite(p)) or not np.isfinite(state.air_moles) or state.air_moles <= 0:
        raise DesignError(f"{what}: the control state needs finite pressures and air_moles > 0 (mol)")
    cells = np.asarray(state.jammed, dtype=np.int64).reshape(-1)
    bad = cells[(cells < 0) | (cells >= design.n_cells)]
    if bad.size:
        raise DesignError(f"{what}: jammed cell {int(bad[0])} does not exist: the design has {design.n_cells} cells")
    if not state.ramp_s > 0:
        raise DesignError(f"{what}: ramp_s must be > 0 s, got {state.ramp_s!r}")


class ScanObservation:
    """A scan of the device and the control state it was taken at.

    ``scan``: a path (any mesh or point cloud trimesh reads: PLY, STL, OBJ, GLB; partial; any pose), an
    (N, 3) array or a mesh; in metres or millimetres (``units`` "auto" detects which, as ``compare``).
    ``result``: the ``ControlResult`` whose sequence the device played, the scan taken ``time`` s into it
    (None: at its end), after the membrane came to rest; or a ``ControlState`` given directly
    (``time`` unused). ``name`` labels it in reports. ``pressure``: the chamber's gauge pressure read
    when the scan was taken (Pa; None: not read), with the sensor's standard deviation
    ``pressure_stderr`` (Pa): a reading fixes the stiffness scale shape alone leaves loose
    (docs/calibration.md). ``held_out``: not fitted; ``calibrate`` predicts it before and after the
    fit (does the calibrated model predict a scan it did not see better?). The points are read and
    checked here."""

    def __init__(self, scan, result=None, time: float | None = None, *, units: str = "auto", name: str | None = None,
                 pressure: float | None = None, pressure_stderr: float = 100.0, held_out: bool = False):
        if not isinstance(result, (ControlResult, ControlState, Sequence)):
            raise DesignError(f"ScanObservation needs the control result (ws.control returns one) or a ControlState "
                              f"it was taken at, got {type(result).__name__}")
        self.name = name or (Path(scan).name if isinstance(scan, (str, Path)) else "scan")
        pts, faces = load_scan(scan)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < MIN_SCAN_POINTS:
            raise ShapeError(f"{self.name}: a scan needs at least {MIN_SCAN_POINTS} points of 3 coordinates, "
                             f"got shape {pts.shape}")
        finite = np.all(np.isfinite(pts), axis=1)
        if not finite.all():
            raise ShapeError(f"{self.name}: scan point {int(np.flatnonzero(~finite)[0])} is not finite")
        self.units = length_unit_of(pts, units, f"scan {self.name}")
        self.points = pts * LENGTH_UNITS[self.units]
        check_scan_spread(self.points)
        self.faces = faces
        self.result, self.time = result, time
        if pressure is not None and not (np.isfinite(pressure) and np.isfinite(pressure_stderr) and pressure_stderr > 0):
            raise DesignError(f"{self.name}: the chamber pressure reading needs a finite pressure (Pa gauge) and "
                              f"pressure_stderr > 0 (Pa), got {pressure!r}, {pressure_stderr!r}")
        self.pressure = None if pressure is None else float(pressure)
        self.pressure_stderr = float(pressure_stderr)
        self.held_out = bool(held_out)

    def sequence(self, design: Design) -> Sequence:
        """The sequence to replay on ``design`` (checked against it: IPAM and cell counts)."""
        what = f"observation {self.name}"
        r = self.result
        if isinstance(r, ControlState):
            check_state(r, design, what)
            sim = SimulationSettings()
            return state_sequence(r, design, sim)
        seq = r if isinstance(r, Sequence) else None
        if seq is None:
            if len(r.ipam_pressures) != design.n_ipams or len(r.jammed) != design.n_cells:
                raise DesignError(f"{what}: its control result drives {len(r.ipam_pressures)} IPAMs and "
                                  f"{len(r.jammed)} cells but the design has {design.n_ipams} IPAMs and "
                                  f"{design.n_cells} cells: a result of another design")
            seq = result_sequence(r, self.time)
        elif seq.pressures.shape[1] != design.n_ipams or seq.jammed.shape[1] != design.n_cells:
            raise DesignError(f"{what}: its control state drives {seq.pressures.shape[1]} IPAMs and "
                              f"{seq.jammed.shape[1]} cells but the design has {design.n_ipams} IPAMs and "
                              f"{design.n_cells} cells; give one pressure per IPAM of the design")
        return seq
