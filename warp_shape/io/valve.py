"""Valve-ready control sequences: what a pressure regulator, a syringe pump and the jamming vacuum
valves of the physical display read, on the lab's clock.

The controller records one row per control step in SI units on the simulator's clock, whose whole
sequence lasts a fraction of a second with pressure and air steps no real valve or pump follows.
The membrane is quasi-static between control steps (every row is a state it settles into), so the
lab may play the same sequence slower: ``ValveTiming`` says how (a pump's flow limit, a valve's
slew limit, a fixed sample grid) and ``row_times`` gives each control step's lab time; the valve
CSV (``valve_schedule``), the USD animation (``usd_animation.playback_times``) and the figures
(``figures``) all use these times, with the simulated time beside them. The simulation itself is
not changed: the lab schedule is the simulated sequence, retimed. The columns of a schedule:

- ``time_s``: lab time, seconds from 0, on the grid (``rate_hz``).
- ``sim_time_s``: the simulated time of the row's state, seconds from 0 (linear between control steps).
- ``phase``: the control law of the row: 1 inflation (the chamber is filled to the target volume,
  IPAMs neutral), 2 shape control, 3 hold (controls held while the membrane comes to rest), 4 the
  model-based controller's planned sequence (ramps within rate limits, holds, jams).
- ``ipam{i}_pressure_kpa``: IPAM i's gauge pressure command in kPa. A *passive* IPAM (not used for
  this target) is held neutral: by default its column carries the simulated neutral pressure, the
  gauge pressure at which its natural length equals its current length so it exerts no force
  (``passive="neutral"``); ``passive="zero"`` writes 0 kPa (vented) instead. Which IPAMs are
  passive is in the sidecar JSON (``passive_ipams``).
- ``control_step``: 1 on the rows that are control steps of the simulated sequence (their controls
  and jam states are the run's own, to 9 digits), 0 on the rows between (ramps). A model replays
  the file from these rows (``calibration.files.valve_sequence``): the sequence the run simulated.
- ``chamber_pressure_kpa``: the chamber's gauge pressure in kPa at rest under the row's controls and
  jams (quasi-static: what a sensor on the chamber reads while the lab plays the schedule slowly;
  the lab doses air, it does not command this pressure). At each control step it is the chamber
  pressure of the static equilibrium reached from the run's frame (``Simulator.settle_static``, each
  jammed cell jammed at the frame it was jammed at), linear between control steps. It is not the
  pressure of the simulated transient: a 60 ms simulated inflation reads below atmospheric while
  its membrane overshoots, a slow lab inflation never does. A record without frames or a design
  keeps the simulated pressure (the sidecar's ``chamber_pressure_source`` says which).
- ``chamber_air_ml``: the chamber's air as a volume at atmospheric pressure and the air temperature
  (the design's material: 101.325 kPa, 293.15 K by default), in mL: n R T / p_atm.
  ``chamber_air_added_ml``: the same less the first row's, what a syringe pump has dosed since t = 0.
- ``cell{j}_jammed``: 1 while cell j's vacuum valve is open (jammed), else 0. A cell the run
  jammed at a control step shows 1 from the row after that step on, while the controls ramp to
  the next step (the simulated run jammed it there, then applied the next controls).

**Retiming** (``ValveTiming``, defaults 5 mL/s, 100 kPa/s, 50 Hz). Each interval between two
control steps is stretched so that the chamber air changes by at most ``max_flow_ml_s`` mL per
second (a syringe pump's flow) and no IPAM pressure column by more than
``max_slew_kpa_s`` kPa per second (a proportional valve's slew); intervals that change slowly keep
their simulated length. Each limit is planned to ``PLAN_MARGIN`` below its value, so the CSV's
printed numbers stay within it. With ``rate_hz`` every interval is then rounded up to whole grid
periods, so every control step falls on the grid (the last row included), and the sequence is
sampled at that rate: pressures, air and simulated time linearly between control steps (which
keeps both limits), phase held from the last control step at or before the sample and jam states
from the next control step (the jam precedes the ramp, as simulated).
"""

from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..controller.worlds import mask_passive, passive_masks
from ..errors import DesignError, SimulationError
from ..material import GAS_CONSTANT
from ..simulator import Simulator
from .atomic import atomic_write, write_json

__all__ = ["DEFAULT_RATE_HZ", "DEFAULT_MAX_SLEW_KPA_S", "DEFAULT_MAX_FLOW_ML_S", "PLAN_MARGIN", "MAX_VALVE_RATE_HZ",
           "MIN_VALVE_SLEW_KPA_S", "MIN_VALVE_FLOW_ML_S", "MAX_VALVE_ROWS", "ValveTiming", "row_times", "peak_rates",
           "valve_schedule", "valve_csv_text", "valve_sidecar", "write_valve_outputs", "quasi_static_pressure",
           "SETTLE_WORLDS"]

DEFAULT_RATE_HZ = 50.0
DEFAULT_MAX_SLEW_KPA_S = 100.0
DEFAULT_MAX_FLOW_ML_S = 5.0
#: each limit is planned to (1 - PLAN_MARGIN) of its value: the CSV's rounded numbers stay within it
PLAN_MARGIN = 1e-3
MAX_VALVE_RATE_HZ = 10_000.0  # past any pressure regulator's update rate
MIN_VALVE_SLEW_KPA_S = 0.1  # slower stretches a 100 kPa step past a quarter of an hour
MIN_VALVE_FLOW_ML_S = 0.01
MAX_VALVE_ROWS = 1_000_000  # about 100 MB of CSV
_REFERENCE = dict(temperature_k=293.15, pressure_pa=101325.0)


@dataclass(frozen=True)
class ValveTiming:
    """How a simulated control sequence is played by the lab's pump and valves (module docstring):
    ``max_flow_ml_s`` the syringe pump's flow limit (mL/s of air at atmospheric pressure),
    ``max_slew_kpa_s`` the valves' slew limit (kPa/s), ``rate_hz`` the sample grid (Hz). None turns
    a limit off (both None: the simulated pace); ``rate_hz`` None keeps one row per control step."""

    rate_hz: float | None = DEFAULT_RATE_HZ
    max_slew_kpa_s: float | None = DEFAULT_MAX_SLEW_KPA_S
    max_flow_ml_s: float | None = DEFAULT_MAX_FLOW_ML_S

    def __post_init__(self):
        for value, what, unit in ((self.rate_hz, "valve rate", "number of samples per second (Hz)"),
                                  (self.max_slew_kpa_s, "valve max slew", "kPa/s"),
                                  (self.max_flow_ml_s, "pump max flow", "mL/s")):
            if value is not None and not (isinstance(value, (int, float, np.floating)) and np.isfinite(value)
                                          and value > 0):
                raise DesignError(f"{what} must be a positive {unit} (or off), got {value!r}")

    def describe(self) -> str:
        """A short line for figure axes and notes: "pump 5 mL/s, valves 100 kPa/s, 50 Hz"."""
        parts = [f"pump {self.max_flow_ml_s:g} mL/s" if self.max_flow_ml_s else "pump unlimited",
                 f"valves {self.max_slew_kpa_s:g} kPa/s" if self.max_slew_kpa_s else "valves unlimited"]
        return ", ".join(parts + ([f"{self.rate_hz:g} Hz"] if self.rate_hz else []))

    def to_dict(self) -> dict:
        return asdict(self)


def _conditions(result) -> tuple[float, float]:
    """(T in K, p_atm in Pa) of the chamber air: the design's material, else 293.15 K, 101.325 kPa."""
    mat = getattr(getattr(result, "design", None), "material", None)
    if mat is None:
        return _REFERENCE["temperature_k"], _REFERENCE["pressure_pa"]
    return float(mat.temperature), float(mat.atmospheric_pressure)


def _counts(history: dict) -> tuple[int, int]:
    n_ipam = sum(1 for c in history if c.startswith("ipam") and c.endswith("_pressure_pa"))
    n_cell = sum(1 for c in history if c.startswith("cell") and c.endswith("_jammed"))
    return n_ipam, n_cell


def _check_passive(passive) -> None:
    if passive not in ("neutral", "zero"):
        raise DesignError(f"passive IPAM pressure must be 'neutral' or 'zero', got {passive!r}")


#: control steps settled together (one world each) by ``quasi_static_pressure``: bounds its memory on
#: large meshes and long sequences
SETTLE_WORLDS = 64


def _jammed_at_their_frames(sim, history: dict, frames: np.ndarray, rows: range, n_cell: int) -> None:
    """Jam the cells of the worlds of control steps ``rows`` (one world each) as the run did: cell j
    where the step's row shows it jammed, its jam taken at the frame of the control step before the
    first row showing it (when the run jammed it, ``controller.open_loop``)."""
    for j in range(n_cell):
        col = np.asarray(history[f"cell{j}_jammed"]).astype(bool)
        if not col[rows.start:rows.stop].any():
            continue
        first = int(np.argmax(col))
        sim.positions = np.broadcast_to(frames[max(first - 1, 0)], (len(rows),) + frames.shape[1:])
        for w, k in enumerate(rows):
            if col[k]:
                sim.jam(j, world=w)


def _settled_pressures(result, frames: np.ndarray, rows: range) -> tuple[np.ndarray, int]:
    """((len(rows),) Pa, how many did not converge): the control steps ``rows`` settled statically."""
    h, design = result.history, result.design
    n_ipam, n_cell = _counts(h)
    sim = Simulator(design, device="cpu", settings=result.settings.simulation.replace(bending="exact"),
                    worlds=len(rows))
    mask_passive(sim, *passive_masks([result] * len(rows), design.n_ipams, design.n_cells))
    _jammed_at_their_frames(sim, h, frames, rows, n_cell)
    sim.positions = frames[rows.start:rows.stop]
    sim.air_moles = np.asarray(h["air_mol"], dtype=np.float64)[rows.start:rows.stop]
    if n_ipam:
        sim.ipam_pressures = np.stack([h[f"ipam{i}_pressure_pa"] for i in range(n_ipam)], axis=1)[rows.start:rows.stop]
    done = sim.settle_static()
    return (np.atleast_1d(np.asarray(sim.pressure(), dtype=np.float64)),
            int(np.count_nonzero(~np.asarray(done.converged, dtype=bool))))


def quasi_static_pressure(result) -> tuple[np.ndarray, str]:
    """((n_rows,) Pa gauge, source): the chamber's pressure at rest under each control step's
    controls and jams (module docstring: a static settle of the control steps, ``SETTLE_WORLDS`` at
    a time, each from its frame, passive actuators masked as in the run), source ``"quasi-static"``;
    a record without frames or design, or one whose settle fails, gives its simulated pressures,
    source ``"simulated ..."`` saying why."""
    h = result.history
    simulated = np.asarray(h["pressure_pa"], dtype=np.float64)
    design, frames = getattr(result, "design", None), getattr(result, "frames", None)
    settings = getattr(getattr(result, "settings", None), "simulation", None)
    if design is None or frames is None or settings is None or len(frames) != len(simulated):
        return simulated, "simulated (the record holds no frames to settle)"
    frames = np.asarray(frames, dtype=np.float64)
    parts, late = [], 0
    try:
        for start in range(0, len(frames), SETTLE_WORLDS):
            p, k = _settled_pressures(result, frames, range(start, min(start + SETTLE_WORLDS, len(frames))))
            parts.append(p)
            late += k
    except SimulationError as exc:
        return simulated, f"simulated (the static settle failed: {exc})"
    p = np.concatenate(parts)
    if not np.all(np.isfinite(p)):
        return simulated, "simulated (the static settle gave non-finite pressures)"
    return p, "quasi-static" + (f" ({late} control steps not fully settled)" if late else "")


def _lab_columns(result, passive: str, chamber=True) -> dict:
    """The history in lab units, one row per control step (simulated times from 0); the chamber's
    quasi-static pressure with ``chamber`` True (a static settle per control step: not needed for
    timing), or ``chamber`` given as ``quasi_static_pressure``'s (Pa, source)."""
    h = result.history
    if "time" not in h or len(h["time"]) == 0:
        raise DesignError("the control result has no history rows; run the controller first")
    n_ipam, n_cell = _counts(h)
    temp, p_atm = _conditions(result)
    passive_set = {int(i) for i in np.atleast_1d(getattr(result, "passive_ipams", []))}
    t = np.asarray(h["time"], dtype=np.float64)
    cols = {"time_s": t - t[0], "sim_time_s": t - t[0], "phase": np.asarray(h["phase"], dtype=np.int64),
            "control_step": np.ones(len(t), dtype=np.int64)}
    for i in range(n_ipam):
        p = np.asarray(h[f"ipam{i}_pressure_pa"], dtype=np.float64) / 1e3
        cols[f"ipam{i}_pressure_kpa"] = np.zeros_like(p) if (passive == "zero" and i in passive_set) else p
    if chamber is not False:
        cols["chamber_pressure_kpa"] = (quasi_static_pressure(result) if chamber is True else chamber)[0] / 1e3
    air_ml = np.asarray(h["air_mol"], dtype=np.float64) * GAS_CONSTANT * temp / p_atm * 1e6
    cols["chamber_air_ml"] = air_ml
    cols["chamber_air_added_ml"] = air_ml - air_ml[0]
    for j in range(n_cell):
        cols[f"cell{j}_jammed"] = np.asarray(h[f"cell{j}_jammed"]).astype(np.int64)
    return cols


def _intervals(cols: dict, timing: ValveTiming) -> np.ndarray:
    """(n_rows - 1,) lab length of each interval between control steps: at least the simulated one,
    its largest pressure change over the slew limit and its air change over the flow limit (both
    planned ``PLAN_MARGIN`` below), in whole grid periods when ``rate_hz``."""
    dt = np.diff(cols["sim_time_s"])
    keep = 1.0 - PLAN_MARGIN
    if timing.max_slew_kpa_s is not None:
        p = np.stack([v for k, v in cols.items() if k.startswith("ipam") and k.endswith("_pressure_kpa")]
                     or [np.zeros(len(dt) + 1)], axis=1)
        dt = np.maximum(dt, np.max(np.abs(np.diff(p, axis=0)), axis=1) / (keep * timing.max_slew_kpa_s))
    if timing.max_flow_ml_s is not None:
        dt = np.maximum(dt, np.abs(np.diff(cols["chamber_air_ml"])) / (keep * timing.max_flow_ml_s))
    if timing.rate_hz is not None:
        dt = np.maximum(1.0, np.ceil(dt * timing.rate_hz - 1e-9)) / timing.rate_hz
    return dt


def _row_ticks(cols: dict, timing: ValveTiming) -> np.ndarray:
    """(n_rows,) lab time of each control step from 0: s, or grid periods (integers) when ``rate_hz``."""
    dt = _intervals(cols, timing)
    if timing.rate_hz is not None:
        dt = np.rint(dt * timing.rate_hz)
    return np.concatenate([[0.0], np.cumsum(dt)])


def row_times(result, timing: ValveTiming | None = None) -> np.ndarray:
    """(n_rows,) lab time in s from 0 of each control step under ``timing`` (default
    ``ValveTiming()``): the times of the valve CSV's control-step rows, of the USD animation's frames
    and of the figures' time axis. ``ValveTiming(None, None, None)``: the simulated times from 0."""
    timing = timing or ValveTiming()
    ticks = _row_ticks(_lab_columns(result, "neutral", chamber=False), timing)
    return ticks / timing.rate_hz if timing.rate_hz is not None else ticks


def _resample(cols: dict, ticks: np.ndarray, rate_hz: float) -> dict:
    """Columns on the grid at ``rate_hz`` from 0 to the last control step (``ticks``: each control
    step's grid index): linear between control steps, jam states and phase held; more than
    ``MAX_VALVE_ROWS`` rows is an error, before any is made."""
    rows = float(ticks[-1]) + 1
    if rows > MAX_VALVE_ROWS:
        raise DesignError(f"the valve sequence would have {rows:.3g} rows ({ticks[-1] / rate_hz:.4g} s at {rate_hz:g} "
                          f"Hz), more than {MAX_VALVE_ROWS}: give a lower rate (--rate) or a faster slew or flow limit "
                          f"(--max-slew, --max-flow)")
    grid = np.arange(int(ticks[-1]) + 1, dtype=np.float64)
    held = np.clip(np.searchsorted(ticks, grid, side="right") - 1, 0, len(ticks) - 1)
    coming = np.clip(np.searchsorted(ticks, grid, side="left"), 0, len(ticks) - 1)
    out = {"time_s": grid / rate_hz}
    for k, v in cols.items():
        if k == "time_s":
            continue
        out[k] = v[held] if k == "phase" else v[coming] if k.endswith("_jammed") else np.interp(grid, ticks, v)
    out["control_step"] = np.zeros(len(grid), dtype=np.int64)
    out["control_step"][ticks.astype(np.int64)] = 1
    return out


def valve_schedule(result, timing: ValveTiming | None = None, *, passive: str = "neutral", chamber=None) -> dict:
    """A control result's sequence in lab units on the lab's clock: column name -> array (module
    docstring). ``timing``: default ``ValveTiming()`` (5 mL/s, 100 kPa/s, 50 Hz); ``chamber``:
    ``quasi_static_pressure(result)`` where already computed."""
    timing = timing or ValveTiming()
    _check_passive(passive)
    cols = _lab_columns(result, passive, chamber if chamber is not None else True)
    ticks = _row_ticks(_lab_columns(result, "neutral", chamber=False) if passive != "neutral" else cols, timing)
    if timing.rate_hz is None or len(ticks) < 2:
        cols["time_s"] = ticks / timing.rate_hz if timing.rate_hz is not None else ticks
        return cols
    return _resample(cols, ticks, timing.rate_hz)


def peak_rates(schedule: dict) -> dict:
    """The fastest change between two rows of a schedule: pump flow (mL/s) and pressure slew (kPa/s)."""
    dt = np.diff(schedule["time_s"])
    if dt.size == 0:
        return dict(flow_ml_s=0.0, slew_kpa_s=0.0)
    p = np.stack([v for k, v in schedule.items() if k.startswith("ipam") and k.endswith("_pressure_kpa")]
                 or [np.zeros(len(dt) + 1)], axis=1)
    return dict(flow_ml_s=float(np.max(np.abs(np.diff(schedule["chamber_air_ml"])) / dt)),
                slew_kpa_s=float(np.max(np.abs(np.diff(p, axis=0)) / dt[:, None])))


def valve_csv_text(schedule: dict) -> str:
    """The schedule as CSV: a header row of column names, then numbers (9 significant digits, no
    comment lines)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    cols = list(schedule)
    w.writerow(cols)
    for row in zip(*(schedule[c] for c in cols)):
        w.writerow([int(v) if isinstance(v, (int, np.integer)) else f"{float(v):.9g}" for v in row])
    return buf.getvalue()


def valve_sidecar(result, schedule: dict, *, target_name: str, timing: ValveTiming | None = None,
                  passive: str = "neutral", chamber_source: str = "quasi-static") -> dict:
    """What the CSV's columns mean, which IPAMs are passive, how the sequence was timed and the
    fastest flow and slew it asks for."""
    timing = timing or ValveTiming()
    temp, p_atm = _conditions(result)
    n_ipam, n_cell = _counts(result.history)
    passive_ipams = sorted(int(i) for i in np.atleast_1d(getattr(result, "passive_ipams", [])))
    units = {"time_s": f"s from the start, lab time ({timing.describe()})",
             "sim_time_s": "s from the start, simulated time of the row's state",
             "phase": "1 inflation, 2 shape control, 3 hold, 4 planned (model-based control)",
             "control_step": "1 a control step of the simulated sequence (its controls and jams as simulated), "
                             "0 a row between two (ramp)",
             "chamber_pressure_kpa": "kPa gauge at rest under the row's controls (quasi-static: what a sensor on "
                                     "the chamber reads when the schedule is played at this pace), "
                                     + chamber_source,
             "chamber_air_ml": f"mL of air at {p_atm / 1e3:g} kPa and {temp:g} K (total in the chamber)",
             "chamber_air_added_ml": "mL at the same conditions, dosed since t = 0"}
    units.update({f"ipam{i}_pressure_kpa": "kPa gauge, command" for i in range(n_ipam)})
    units.update({f"cell{j}_jammed": "1 vacuum on (jammed), 0 off" for j in range(n_cell)})
    note = ("passive IPAMs are not used for this target and held neutral: their column is the gauge "
            "pressure that keeps them force-free at their current length" if passive == "neutral" else
            "passive IPAMs are not used for this target: vented, their column is 0 kPa")
    t = schedule["time_s"]
    return dict(target=target_name, csv=f"valve_{target_name}.csv", columns=units,
                passive_ipams=passive_ipams, passive_ipam_pressure=passive, passive_note=note,
                chamber_pressure_source=chamber_source,
                passive_cells=sorted(int(j) for j in np.atleast_1d(getattr(result, "passive_cells", []))),
                **timing.to_dict(), duration_s=float(t[-1]), rows=len(t), peak=peak_rates(schedule),
                air_reference=dict(temperature_k=temp, pressure_kpa=p_atm / 1e3),
                simulated_duration_s=float(result.history["time"][-1] - result.history["time"][0]))


def write_valve_outputs(results, names, out_dir, timing: ValveTiming | None = None, *,
                        passive: str = "neutral") -> list[Path]:
    """Per target ``valve_<name>.csv`` (lab units, lab clock) and ``valve_<name>.json`` (its sidecar)."""
    out = Path(out_dir)
    written = []
    for name, res in zip(names, results):
        chamber = quasi_static_pressure(res)
        sched = valve_schedule(res, timing, passive=passive, chamber=chamber)
        side = valve_sidecar(res, sched, target_name=name, timing=timing, passive=passive, chamber_source=chamber[1])
        written.append(atomic_write(out / f"valve_{name}.csv", valve_csv_text(sched)))
        written.append(write_json(out / f"valve_{name}.json", side))
    return written
