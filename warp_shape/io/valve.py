"""Valve-ready control sequences: what a pressure regulator, a syringe pump and the jamming vacuum
valves of the physical display read.

The controller records one row per control step in SI units on the simulator's clock, whose whole
sequence lasts a fraction of a second with pressure steps no real valve follows. ``valve_schedule``
turns a control result into lab units and a lab pace:

- ``time_s``: seconds from 0.
- ``phase``: the control law of the row: 1 inflation (the chamber is filled to the target volume,
  IPAMs neutral), 2 shape control, 3 hold (controls held while the membrane comes to rest), 4 the
  model-based controller's planned sequence (ramps within rate limits, holds, jams).
- ``ipam{i}_pressure_kpa``: IPAM i's gauge pressure in kPa. A *passive* IPAM (not used for this
  target) is held neutral: by default its column carries the simulated neutral pressure, the gauge
  pressure at which its natural length equals its current length so it exerts no force (``passive=
  "neutral"``); ``passive="zero"`` writes 0 kPa (vented) instead. Which IPAMs are passive is in
  the sidecar JSON (``passive_ipams``).
- ``chamber_pressure_kpa``: the chamber's gauge pressure in kPa (measured in the simulation: what a
  pressure sensor on the chamber should read).
- ``chamber_air_ml``: the chamber's air as a volume at atmospheric pressure and the air temperature
  (the design's material: 101.325 kPa, 293.15 K by default), in mL: n R T / p_atm.
  ``chamber_air_added_ml``: the same less the first row's, what a syringe pump has dosed since t = 0.
- ``cell{j}_jammed``: 1 while cell j's vacuum valve is open (jammed), else 0.

**Re-timing.** The simulated sequence is quasi-static (each row is a state the membrane settles
into), so it may be played slower. With ``max_slew_kpa_s`` every interval between two rows is
stretched so that no pressure column (IPAMs and chamber) changes faster than that many kPa per
second, and with ``max_flow_ml_s`` so that the chamber air changes by at most that many mL per
second (a syringe pump's flow); intervals whose change is slow keep their simulated length. With ``rate_hz`` the stretched
sequence is resampled on a uniform clock at that rate: pressures and air linearly (which keeps the
slew limit), jam states held from the last row at or before each sample. The last sample is the
end of the sequence.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..errors import DesignError
from ..material import GAS_CONSTANT
from .atomic import atomic_write, write_json

__all__ = ["DEFAULT_RATE_HZ", "DEFAULT_MAX_SLEW_KPA_S", "MAX_VALVE_RATE_HZ", "MIN_VALVE_SLEW_KPA_S",
           "MIN_VALVE_FLOW_ML_S", "MAX_VALVE_ROWS", "row_times", "valve_schedule", "valve_csv_text",
           "valve_sidecar", "write_valve_outputs"]

DEFAULT_RATE_HZ = 50.0
DEFAULT_MAX_SLEW_KPA_S = 100.0
MAX_VALVE_RATE_HZ = 10_000.0  # past any pressure regulator's update rate
MIN_VALVE_SLEW_KPA_S = 0.1  # slower stretches a 100 kPa step past a quarter of an hour
MIN_VALVE_FLOW_ML_S = 0.01
MAX_VALVE_ROWS = 1_000_000  # about 100 MB of CSV
_REFERENCE = dict(temperature_k=293.15, pressure_pa=101325.0)


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


def _check_options(rate_hz, max_slew_kpa_s, passive, max_flow_ml_s=None) -> None:
    if max_flow_ml_s is not None and not (np.isfinite(max_flow_ml_s) and max_flow_ml_s > 0):
        raise DesignError(f"valve max flow must be a positive mL/s, got {max_flow_ml_s}")
    if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
        raise DesignError(f"valve rate must be a positive number of samples per second (Hz), got {rate_hz}")
    if max_slew_kpa_s is not None and not (np.isfinite(max_slew_kpa_s) and max_slew_kpa_s > 0):
        raise DesignError(f"valve max slew must be a positive kPa/s, got {max_slew_kpa_s}")
    if passive not in ("neutral", "zero"):
        raise DesignError(f"passive IPAM pressure must be 'neutral' or 'zero', got {passive!r}")


def _lab_columns(result, passive: str) -> dict:
    """The history in lab units, one row per control step (times not yet shifted or stretched)."""
    h = result.history
    if "time" not in h or len(h["time"]) == 0:
        raise DesignError("the control result has no history rows; run the controller first")
    n_ipam, n_cell = _counts(h)
    temp, p_atm = _conditions(result)
    passive_set = {int(i) for i in np.atleast_1d(getattr(result, "passive_ipams", []))}
    cols = {"time_s": np.asarray(h["time"], dtype=np.float64), "phase": np.asarray(h["phase"], dtype=np.int64)}
    for i in range(n_ipam):
        p = np.asarray(h[f"ipam{i}_pressure_pa"], dtype=np.float64) / 1e3
        cols[f"ipam{i}_pressure_kpa"] = np.zeros_like(p) if (passive == "zero" and i in passive_set) else p
    cols["chamber_pressure_kpa"] = np.asarray(h["pressure_pa"], dtype=np.float64) / 1e3
    air_ml = np.asarray(h["air_mol"], dtype=np.float64) * GAS_CONSTANT * temp / p_atm * 1e6
    cols["chamber_air_ml"] = air_ml
    cols["chamber_air_added_ml"] = air_ml - air_ml[0]
    for j in range(n_cell):
        cols[f"cell{j}_jammed"] = np.asarray(h[f"cell{j}_jammed"]).astype(np.int64)
    return cols


def row_times(result, max_slew_kpa_s: float | None = DEFAULT_MAX_SLEW_KPA_S,
              max_flow_ml_s: float | None = None) -> np.ndarray:
    """(n_rows,) time in s from 0 of each control step once stretched to ``max_slew_kpa_s`` and
    ``max_flow_ml_s`` (both None: the simulated times, shifted to start at 0). Used by the valve CSV
    and by the USD animation's real-duration playback."""
    _check_options(None, max_slew_kpa_s, "neutral", max_flow_ml_s)
    return _stretched(_lab_columns(result, "neutral"), max_slew_kpa_s, max_flow_ml_s)


def _stretched(cols: dict, max_slew_kpa_s: float | None, max_flow_ml_s: float | None = None) -> np.ndarray:
    """Row times from 0, each interval at least as long as its largest pressure change over the
    slew limit and its air change over the flow limit."""
    t = cols["time_s"] - cols["time_s"][0]
    if len(t) < 2:
        return t
    dt = np.diff(t)
    if max_slew_kpa_s is not None:
        p = np.stack([v for k, v in cols.items() if k.endswith("_pressure_kpa")], axis=1)
        dt = np.maximum(dt, np.max(np.abs(np.diff(p, axis=0)), axis=1) / max_slew_kpa_s)
    if max_flow_ml_s is not None:
        dt = np.maximum(dt, np.abs(np.diff(cols["chamber_air_ml"])) / max_flow_ml_s)
    return np.concatenate([[0.0], np.cumsum(dt)])


def _resample(cols: dict, t: np.ndarray, rate_hz: float) -> dict:
    """Columns on a uniform clock at ``rate_hz`` (linear; jam states and phase held), ending at t[-1];
    more than ``MAX_VALVE_ROWS`` rows is an error, before any is made."""
    rows = float(np.floor(t[-1] * rate_hz + 1e-9)) + 1
    if rows > MAX_VALVE_ROWS:
        raise DesignError(f"the valve sequence would have {rows:.3g} rows ({t[-1]:.4g} s at {rate_hz:g} Hz), more "
                          f"than {MAX_VALVE_ROWS}: give a lower rate (--rate) or a faster slew or flow limit "
                          f"(--max-slew, --max-flow)")
    n = int(rows)
    ts = np.arange(n) / rate_hz
    if ts[-1] < t[-1] - 1e-12:
        ts = np.append(ts, t[-1])
    held = np.clip(np.searchsorted(t, ts + 1e-12, side="right") - 1, 0, len(t) - 1)
    out = {"time_s": ts}
    for k, v in cols.items():
        if k == "time_s":
            continue
        out[k] = v[held] if (k == "phase" or k.endswith("_jammed")) else np.interp(ts, t, v)
    return out


def valve_schedule(result, *, rate_hz: float | None = DEFAULT_RATE_HZ,
                   max_slew_kpa_s: float | None = DEFAULT_MAX_SLEW_KPA_S, max_flow_ml_s: float | None = None,
                   passive: str = "neutral") -> dict:
    """A control result's sequence in lab units and pace: column name -> array (module docstring).
    ``rate_hz`` None keeps one row per control step; ``max_slew_kpa_s`` and ``max_flow_ml_s`` None
    keep the simulated timing."""
    _check_options(rate_hz, max_slew_kpa_s, passive, max_flow_ml_s)
    cols = _lab_columns(result, passive)
    t = _stretched(cols, max_slew_kpa_s, max_flow_ml_s)
    cols["time_s"] = t
    return _resample(cols, t, rate_hz) if rate_hz is not None and len(t) > 1 else cols


def valve_csv_text(schedule: dict) -> str:
    """The schedule as CSV: a header row of column names, then numbers (no comment lines)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    cols = list(schedule)
    w.writerow(cols)
    for row in zip(*(schedule[c] for c in cols)):
        w.writerow([int(v) if isinstance(v, (int, np.integer)) else f"{float(v):.6g}" for v in row])
    return buf.getvalue()


def valve_sidecar(result, schedule: dict, *, target_name: str, rate_hz, max_slew_kpa_s, passive: str,
                  max_flow_ml_s=None) -> dict:
    """What the CSV's columns mean, which IPAMs are passive and how the sequence was timed."""
    temp, p_atm = _conditions(result)
    n_ipam, n_cell = _counts(result.history)
    passive_ipams = sorted(int(i) for i in np.atleast_1d(getattr(result, "passive_ipams", [])))
    units = {"time_s": "s from the start", "phase": "1 inflation, 2 shape control, 3 hold, 4 planned (model-based control)",
             "chamber_pressure_kpa": "kPa gauge (measured)",
             "chamber_air_ml": f"mL of air at {p_atm / 1e3:g} kPa and {temp:g} K (total in the chamber)",
             "chamber_air_added_ml": "mL at the same conditions, dosed since t = 0"}
    units.update({f"ipam{i}_pressure_kpa": "kPa gauge" for i in range(n_ipam)})
    units.update({f"cell{j}_jammed": "1 vacuum on (jammed), 0 off" for j in range(n_cell)})
    note = ("passive IPAMs are not used for this target and held neutral: their column is the gauge "
            "pressure that keeps them force-free at their current length" if passive == "neutral" else
            "passive IPAMs are not used for this target: vented, their column is 0 kPa")
    t = schedule["time_s"]
    return dict(target=target_name, csv=f"valve_{target_name}.csv", columns=units,
                passive_ipams=passive_ipams, passive_ipam_pressure=passive, passive_note=note,
                passive_cells=sorted(int(j) for j in np.atleast_1d(getattr(result, "passive_cells", []))),
                rate_hz=rate_hz, max_slew_kpa_s=max_slew_kpa_s, max_flow_ml_s=max_flow_ml_s,
                duration_s=float(t[-1]), rows=len(t),
                air_reference=dict(temperature_k=temp, pressure_kpa=p_atm / 1e3),
                simulated_duration_s=float(result.history["time"][-1] - result.history["time"][0]))


def write_valve_outputs(results, names, out_dir, *, rate_hz: float | None = DEFAULT_RATE_HZ,
                        max_slew_kpa_s: float | None = DEFAULT_MAX_SLEW_KPA_S, max_flow_ml_s: float | None = None,
                        passive: str = "neutral") -> list[Path]:
    """Per target ``valve_<name>.csv`` (lab units, re-timed) and ``valve_<name>.json`` (its sidecar)."""
    out = Path(out_dir)
    written = []
    opts = dict(rate_hz=rate_hz, max_slew_kpa_s=max_slew_kpa_s, max_flow_ml_s=max_flow_ml_s, passive=passive)
    for name, res in zip(names, results):
        sched = valve_schedule(res, **opts)
        side = valve_sidecar(res, sched, target_name=name, **opts)
        written.append(atomic_write(out / f"valve_{name}.csv", valve_csv_text(sched)))
        written.append(write_json(out / f"valve_{name}.json", side))
    return written
