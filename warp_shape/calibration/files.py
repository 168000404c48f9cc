"""Calibration files: the observation manifest, the calibration file, the report and residual maps.

The calibration file is a small versioned JSON in SI units (``write_calibration``, ``read_calibration``);
``apply_calibration`` gives a design its fitted values, and ``design``, ``control`` and ``export`` take
one with ``--calibration FILE``. The manifest lists the observations: each a scan file and the control
state it was taken at (a row or lab time of a ``valve_<target>.csv``, a row or simulated time of a
``control_<target>.csv``, or the state given directly);
every path in it is relative to its folder and must stay inside it.
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import math
from pathlib import Path

import numpy as np

from ..display import Design
from ..errors import DesignError, read_input_file
from ..io.atomic import atomic_write, write_json
from ..material import GAS_CONSTANT
from ..simulation_settings import SimulationSettings
from .observations import ControlState, ScanObservation, Sequence
from .parameters import BOUNDS, CALIBRATION_PARAMETERS, RELATIVE_BOUND, apply_values, check_wrt
from .regions import region_faces
from .result import CalibrationResult

__all__ = ["CALIBRATION_FORMAT", "CALIBRATION_VERSION", "UNITS", "calibration_data", "write_calibration",
           "read_calibration", "apply_calibration", "read_manifest", "calibration_markdown", "bounds_reached",
           "write_residual_figures", "build_residual_figure", "residual_scale_mm", "valve_sequence",
           "control_sequence"]

CALIBRATION_FORMAT = "warp-shape calibration"
CALIBRATION_VERSION = 1
#: the unit of every value in a calibration file
UNITS = {"youngs_modulus": "Pa", "thickness": "m", "bending_stiffness": "N m/rad", "ipam_stiffness": "N/m",
         "ipam_area": "m^2", "rest_scale": "1", "region_stretch": "1 (multiplier of E t on the region's faces)",
         "shear_modulus": "Pa", "yeoh_c2": "Pa", "yeoh_c3": "Pa",
         "residual_mm": "mm"}


def _plain(v):
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 0:
        return float(a) if math.isfinite(float(a)) else None
    return [float(x) if math.isfinite(x) else None for x in a.tolist()]


def calibration_data(result: CalibrationResult, design: Design) -> dict:
    """The calibration file's content (a JSON-ready dict, SI units named in ``units``)."""
    return {"format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION, "units": UNITS,
            "design": {"vertices": design.rest.n_vertices, "faces": design.rest.n_faces, "ipams": design.n_ipams,
                       "cells": design.n_cells, "membrane": design.material.membrane},
            "values": {k: _plain(v) for k, v in result.values.items()},
            "regions": {k: [int(f) for f in v] for k, v in result.regions.items()},
            "stderr": {k: _plain(v) for k, v in result.stderr.items()},
            "start": {k: _plain(v) for k, v in result.start.items()},
            "unidentifiable": list(result.unidentifiable), "notes": list(result.notes),
            "poorly_determined": list(result.poorly_determined), "realigned": list(result.realigned),
            "at_bounds": bounds_reached(result),
            "residual_mm": [float(x) for x in result.residual_mm],
            "initial_residual_mm": [float(x) for x in result.initial_residual_mm],
            "observations": list(result.observation_names), "noise_mm": _plain(result.noise_mm),
            "model_error_mm": _plain(result.model_error_mm), "stderr_scale": _plain(result.error_scale),
            "z": {k: _plain(v) for k, v in result.z.items()}, "flags": list(result.flags),
            "held_out": [{"scan": n, "rms_before_mm": a, "rms_after_mm": b} for n, a, b in result.held_out]}


def bounds_reached(result: CalibrationResult) -> list[str]:
    """The fitted values that ended at a bound of the fit (its physical range, or a factor
    ``RELATIVE_BOUND`` from the start), each as a line naming the bound: the fit wanted to go further,
    so the value and its standard error say less than they seem to."""
    lines = []
    labels = iter(result.labels)
    for label, start, value, _ in _rows_plain(result, labels):
        name = label.split("[")[0]
        lo, hi = BOUNDS.get(name, (0.0, math.inf))
        lo, hi = max(lo, start / RELATIVE_BOUND), min(hi, start * RELATIVE_BOUND)
        for bound, side in ((lo, "lower"), (hi, "upper")):
            if math.isfinite(value) and abs(value - bound) <= 1e-3 * bound:
                why = (f"{RELATIVE_BOUND:g}x its start {start:.4g}" if bound in (start / RELATIVE_BOUND,
                                                                                   start * RELATIVE_BOUND)
                       else "its physical range")
                lines.append(f"{label} = {value:.4g} is at its {side} bound ({why}): the fit wanted to go further; "
                             f"check the scans' units and states, or start from a closer design")
    return lines


def _rows_plain(result: CalibrationResult, labels):
    for name, value in result.values.items():
        v, s0 = (np.atleast_1d(np.asarray(x, dtype=np.float64)) for x in (value, result.start[name]))
        for j in range(v.size):
            yield next(labels, name), float(s0[j]), float(v[j]), None


def write_calibration(result: CalibrationResult, design: Design, path) -> Path:
    """Write the calibration file (atomically)."""
    return write_json(Path(path), calibration_data(result, design))


#: the keys a manifest, one of its observations and a given state may have
MANIFEST_KEYS = ("observations", "wrt", "regions")
OBSERVATION_KEYS = ("scan", "units", "name", "chamber_pressure_kpa", "pressure_stderr_kpa", "valve", "control",
                    "state", "row", "time_s", "held_out")
STATE_KEYS = ("air_mol", "ipam_pressures_kpa", "jammed")


def _json_file(path: Path, what: str, missing: str = "", bad: str = ""):
    """The JSON content of ``path``; a missing file, one that is no regular file (a folder, a FIFO, a
    device) or unreadable is a one-line ``DesignError`` naming ``what`` it should be, ``missing`` /
    ``bad`` appended (what to do instead)."""
    if not path.exists() and not path.is_symlink():
        raise DesignError(f"{what} {path} does not exist{missing}")
    try:
        return json.loads(read_input_file(path, what, DesignError))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DesignError(f"{what} {path} is not JSON ({exc}){bad}") from None
    except RecursionError:
        raise DesignError(f"{what} {path} is nested too deeply to be one{bad}") from None


def _known_keys(data: dict, known, where: str) -> None:
    """Every key of ``data`` one of ``known``: an unknown one (a misspelt key is otherwise ignored) is a
    one-line error naming the closest known key."""
    for key in data:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1, cutoff=0.5)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise DesignError(f"{where}: unknown key {key!r}; {hint}the keys are {', '.join(known)}")


def _finite(value, where: str, positive: bool = False) -> float:
    """``value`` as a finite float (a JSON number, not a bool or a string); ``positive``: > 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (positive and not value > 0):
        raise DesignError(f"{where} must be a finite {'positive ' if positive else ''}number, got {value!r}")
    return float(value)


def _row_index(value, where: str) -> int:
    """A row number: a whole number >= 0 (2.5 is not read as 2, nor true as 1)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise DesignError(f"{where} must be a whole row number >= 0, got {value!r}")
    return value


def read_calibration(path) -> dict:
    """{name: value} of a calibration file, checked (format, version, known parameters, positive
    numbers); a bad file is a one-line ``DesignError``."""
    path = Path(path)
    data = _json_file(path, "calibration file", missing="; write one with warp-shape calibrate",
                      bad="; give a file warp-shape calibrate wrote")
    if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT:
        raise DesignError(f"{path} is not a calibration file (no \"format\": \"{CALIBRATION_FORMAT}\")")
    if data.get("version") != CALIBRATION_VERSION:
        raise DesignError(f"calibration file {path} has version {data.get('version')!r}; this warp-shape reads "
                          f"version {CALIBRATION_VERSION}")
    values = data.get("values")
    if not isinstance(values, dict) or not values:
        raise DesignError(f"calibration file {path} holds no values")
    check_wrt(tuple(values))
    out = {}
    for k, v in values.items():
        listed = isinstance(v, list) and k in ("ipam_stiffness", "ipam_area", "region_stretch")  # per IPAM/region
        items = v if listed else [v]
        if not items or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and x > 0)
                            for x in items):
            shape = "a finite positive number" + (" or a list of them (one per IPAM or region)"
                                                  if k in ("ipam_stiffness", "ipam_area", "region_stretch") else "")
            raise DesignError(f"calibration file {path}: {k} must be {shape} ({UNITS.get(k)}), got {v!r}")
        out[k] = np.asarray(items, dtype=np.float64) if listed else float(v)
    out["_design"] = data.get("design", {})
    regions = data.get("regions") or {}
    if ("region_stretch" in out) != bool(regions) or not isinstance(regions, dict) or (
            "region_stretch" in out and np.size(out["region_stretch"]) != len(regions)):
        raise DesignError(f"calibration file {path}: region_stretch and its \"regions\" (face lists) do not match; "
                          f"give a file warp-shape calibrate wrote")
    try:
        out["_regions"] = {str(k): np.asarray(v, dtype=np.int64).reshape(-1) for k, v in regions.items()}
    except (TypeError, ValueError):
        raise DesignError(f"calibration file {path}: \"regions\" must map names to face indices") from None
    return out


def apply_calibration(design: Design, calibration) -> Design:
    """``design`` with a calibration's values (a file path or ``read_calibration``'s dict): a file of
    another design (other IPAM count) is a one-line ``DesignError``."""
    values = read_calibration(calibration) if isinstance(calibration, (str, Path)) else dict(calibration)
    made_for = values.pop("_design", {}) or {}
    regions = values.pop("_regions", {}) or {}
    n = made_for.get("ipams")
    if n is not None and n != design.n_ipams and any(k.startswith("ipam_") for k in values):
        raise DesignError(f"the calibration was fitted on a design with {n} IPAMs; this design has "
                          f"{design.n_ipams}: calibrate this design, or use a file of it")
    nf = made_for.get("faces")
    if regions and nf is not None and nf != design.rest.n_faces:
        raise DesignError(f"the calibration's regions are faces of a membrane with {nf} faces; this design has "
                          f"{design.rest.n_faces}: calibrate this design, or use a file of it")
    return apply_values(design, values, regions=regions)


def material_values(calibration) -> dict:
    """The material fields of a calibration (for a new design's material: ``design --calibration``); a
    hyperelastic membrane's constants come with its law (``membrane``, as the calibrated design had it)."""
    values = read_calibration(calibration) if isinstance(calibration, (str, Path)) else dict(calibration)
    out = {k: values[k] for k in ("youngs_modulus", "thickness", "bending_stiffness", "shear_modulus", "yeoh_c2",
                                  "yeoh_c3") if k in values}
    if any(k in out for k in ("shear_modulus", "yeoh_c2", "yeoh_c3")):
        law = (values.get("_design") or {}).get("membrane")
        out["membrane"] = law if law in ("neo_hookean", "yeoh") else "yeoh" if "yeoh_c2" in out or "yeoh_c3" in out \
            else "neo_hookean"
    return out


def ipam_values(calibration) -> dict:
    """The mean fitted IPAM stiffness and area of a calibration (for the IPAMs a new design adds)."""
    values = read_calibration(calibration) if isinstance(calibration, (str, Path)) else dict(calibration)
    return {k: float(np.mean(values[k])) for k in ("ipam_stiffness", "ipam_area") if k in values}


def _inside(folder: Path, name, what: str) -> Path:
    """``name`` (relative to ``folder``) as a path inside ``folder``; outside it is a one-line error."""
    if not isinstance(name, str) or not name:
        raise DesignError(f"manifest {what}: give a file name relative to the manifest's folder, got {name!r}")
    path = (folder / name).resolve()
    if not path.is_relative_to(folder.resolve()):
        raise DesignError(f"manifest {what} {name!r} points outside the manifest's folder {folder}; copy the file "
                          f"next to the manifest")
    if not path.is_file():
        raise DesignError(f"manifest {what} {name!r}: no such file in {folder}")
    return path


def _schedule_rows(path: Path, design: Design, need: list, pressure: str, kind: str) -> list[dict]:
    """The rows of a schedule CSV of ``design`` (columns ``need`` and one ``ipam<i>_<pressure>`` per IPAM)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    need = need + [f"ipam{i}_{pressure}" for i in range(design.n_ipams)]
    cols = rows[0].keys() if rows else []
    missing = [c for c in need if c not in cols]
    if missing:
        raise DesignError(f"{path.name} is not a {kind} of this design: no column {missing[0]!r}")
    n_csv = sum(1 for c in cols if c.startswith("ipam") and c.endswith(f"_{pressure}"))
    if n_csv != design.n_ipams:
        raise DesignError(f"{path.name} drives {n_csv} IPAMs but the design has {design.n_ipams}: a {kind} of "
                          f"another design")
    return rows


def _column(rows: list, col: str, path: Path, scale: float = 1.0) -> np.ndarray:
    """Column ``col`` of a schedule's rows as finite floats; a cell that is no finite number is a
    one-line error naming its row."""
    out = np.empty(len(rows))
    for i, r in enumerate(rows):
        try:
            out[i] = float(r[col])
        except (TypeError, ValueError):
            out[i] = np.nan
        if not math.isfinite(out[i]):
            raise DesignError(f"{path.name} row {i}: {col} is {r[col]!r}, not a finite number; give a file "
                              f"warp-shape wrote (or fix that cell)")
    return out * scale


def _up_to(rows: list, times: np.ndarray, row, time_s, name: str) -> list:
    """``rows`` up to ``row`` (0-based) or the last one at or before ``time_s`` (on the clock ``times``);
    all of them for neither."""
    last = len(rows) - 1 if row is None and time_s is None else \
        (int(row) if row is not None else int(np.searchsorted(times, float(time_s) + 1e-9)) - 1)
    if not 0 <= last < len(rows):
        raise DesignError(f"{name}: row/time outside the schedule ({len(rows)} rows, 0 to {times[-1]:.3f} s)")
    return rows[: last + 1]


def _jams(rows: list, design: Design) -> np.ndarray:
    jam = np.array([[r.get(f"cell{j}_jammed", "0") in ("1", "True") for j in range(design.n_cells)] for r in rows],
                   bool)
    return np.maximum.accumulate(jam.reshape(len(rows), design.n_cells), axis=0)


def valve_sequence(path: Path, design: Design, *, row: int | None = None, time_s: float | None = None) -> Sequence:
    """The sequence of a ``valve_<target>.csv`` up to ``row`` (0-based) or lab time ``time_s`` (None
    and None: its end): simulated times, the chamber air (mL at atmospheric pressure -> mol, the
    design's temperature and atmosphere), IPAM pressures (kPa -> Pa) and jam states."""
    rows = _schedule_rows(path, design, ["time_s", "sim_time_s", "chamber_air_ml"], "pressure_kpa", "valve schedule")
    rows = _up_to(rows, _column(rows, "time_s", path), row, time_s, path.name)
    if "control_step" in rows[0]:  # the simulated sequence's own rows (and the chosen row, if between)
        rows = [r for k, r in enumerate(rows) if str(r["control_step"]).strip() == "1" or k == len(rows) - 1]
    mat = design.material
    air = _column(rows, "chamber_air_ml", path) * 1e-6 * mat.atmospheric_pressure / (GAS_CONSTANT * mat.temperature)
    p = np.stack([_column(rows, f"ipam{i}_pressure_kpa", path, 1e3) for i in range(design.n_ipams)], axis=1) \
        if design.n_ipams else np.zeros((len(rows), 0))
    times = _column(rows, "sim_time_s", path)
    return Sequence(times - times[0], air, p.reshape(len(rows), design.n_ipams), _jams(rows, design),
                    *_passive_of(path), simulation=SimulationSettings())


def _passive_of(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(passive IPAMs, passive cells) of a valve schedule, from its sidecar ``valve_<target>.json``
    beside it (none where there is none): the run left them out, its replay masks them out too."""
    side = path.with_suffix(".json")
    try:
        data = json.loads(side.read_text()) if side.is_file() else {}
        return tuple(np.asarray(data.get(k, []), np.int64).reshape(-1) for k in ("passive_ipams", "passive_cells"))
    except (OSError, ValueError, TypeError):
        raise DesignError(f"{side.name} beside {path.name} is not the schedule's sidecar (JSON with passive_ipams, "
                          f"passive_cells); give the valve_<target>.json written with it") from None


def control_sequence(path: Path, design: Design, *, row: int | None = None, time_s: float | None = None) -> Sequence:
    """The sequence of a ``control_<target>.csv`` (a control result's history, simulated time) up to
    ``row`` (0-based) or simulated time ``time_s`` (None and None: its end): times, air (mol), IPAM
    pressures (Pa) and jam states, as ``ScanObservation`` takes them from the result itself."""
    rows = _schedule_rows(path, design, ["time", "air_mol"], "pressure_pa", "control history")
    rows = _up_to(rows, _column(rows, "time", path), row, time_s, path.name)
    air = _column(rows, "air_mol", path)
    p = np.stack([_column(rows, f"ipam{i}_pressure_pa", path) for i in range(design.n_ipams)], axis=1) \
        if design.n_ipams else np.zeros((len(rows), 0))
    times = _column(rows, "time", path)
    return Sequence(times - times[0], air, p.reshape(len(rows), design.n_ipams), _jams(rows, design),
                    simulation=SimulationSettings())


def _state(entry: dict, what: str) -> ControlState:
    s = entry["state"]
    if not isinstance(s, dict) or "air_mol" not in s:
        raise DesignError(f"manifest {what}: \"state\" must be an object with air_mol, ipam_pressures_kpa, jammed")
    _known_keys(s, STATE_KEYS, f"manifest {what} state")
    pressures, jammed = s.get("ipam_pressures_kpa", []), s.get("jammed", [])
    if not isinstance(pressures, list) or not isinstance(jammed, list):
        raise DesignError(f"manifest {what} state: ipam_pressures_kpa (one per IPAM) and jammed (cell indices) "
                          f"are lists")
    return ControlState(air_moles=_finite(s["air_mol"], f"manifest {what} state air_mol (mol)", positive=True),
                        ipam_pressures=tuple(_finite(p, f"manifest {what} state ipam_pressures_kpa") * 1e3
                                             for p in pressures),
                        jammed=tuple(_row_index(j, f"manifest {what} state jammed (a cell index)") for j in jammed))


def _reading(entry: dict, what: str) -> dict:
    """The chamber pressure reading of a manifest entry (``chamber_pressure_kpa``, ``pressure_stderr_kpa``)."""
    if entry.get("chamber_pressure_kpa") is None:
        if "pressure_stderr_kpa" in entry:
            raise DesignError(f"manifest {what}: pressure_stderr_kpa without chamber_pressure_kpa; give the reading too")
        return {}
    return dict(pressure=_finite(entry["chamber_pressure_kpa"], f"manifest {what} chamber_pressure_kpa") * 1e3,
                pressure_stderr=_finite(entry.get("pressure_stderr_kpa", 0.1), f"manifest {what} pressure_stderr_kpa",
                                        positive=True) * 1e3)


def _text(entry: dict, key: str, what: str, default: str) -> str:
    value = entry.get(key, default)
    if not isinstance(value, str):
        raise DesignError(f"manifest {what}: {key} must be a string, got {value!r}")
    return value


def _observed_state(e: dict, folder: Path, design: Design, what: str):
    """The state an observation's scan was taken at: a schedule file up to a row or time, or given."""
    sources = [k for k in ("valve", "control", "state") if k in e]
    if len(sources) != 1:
        raise DesignError(f"manifest {what}: give the state the scan was taken at, once: \"valve\" or \"control\" "
                          f"(with \"row\" or \"time_s\") or \"state\"" + (f"; it gives {' and '.join(sources)}"
                                                                               if sources else ""))
    picks = [k for k in ("row", "time_s") if k in e]
    if sources[0] == "state":
        if picks:
            raise DesignError(f"manifest {what}: {' and '.join(picks)} select a point of a \"valve\" or \"control\" "
                              f"file; leave them out of an observation with a given \"state\"")
        return _state(e, what)
    if len(picks) == 2:
        raise DesignError(f"manifest {what}: give \"row\" or \"time_s\", not both")
    row = _row_index(e["row"], f"manifest {what} row") if "row" in e else None
    time_s = _finite(e["time_s"], f"manifest {what} time_s (s)") if "time_s" in e else None
    read = valve_sequence if sources[0] == "valve" else control_sequence
    return read(_inside(folder, e[sources[0]], f"{what} {sources[0]}"), design, row=row, time_s=time_s)


def read_manifest(path, design: Design) -> tuple[list[ScanObservation], tuple | None, list | None]:
    """(observations, wrt or None) of a manifest file (JSON): ``{"observations": [{"scan": FILE, "units":
    "auto", optionally "chamber_pressure_kpa" (a reading) and "pressure_stderr_kpa" (default 0.1), and
    "valve": FILE (a ``valve_<target>.csv``; "row" or "time_s" on its lab clock) or "control": FILE (a
    ``control_<target>.csv``; "row" or simulated "time_s"), or "state": {"air_mol", "ipam_pressures_kpa",
    "jammed"}}, optionally "held_out": true (predicted before and after the fit, not fitted), ...],
    "wrt": [...], "regions": [...]}`` (``regions``: of ``calibrate``). Returns (observations, wrt or None,
    regions or None). Every path is relative to the manifest's folder and must stay in it;
    each observation's state is checked against ``design``. Errors are one line, before any work."""
    path = Path(path)
    data = _json_file(path, "manifest")
    if isinstance(data, dict):
        _known_keys(data, MANIFEST_KEYS, f"manifest {path}")
    entries = data.get("observations") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise DesignError(f"manifest {path} lists no observations (\"observations\": [{{\"scan\": ..., ...}}])")
    folder, obs = path.parent, []
    for k, e in enumerate(entries):
        what = f"observation {k}"
        if not isinstance(e, dict) or "scan" not in e:
            raise DesignError(f"manifest {what}: an observation is an object with \"scan\" and its state")
        _known_keys(e, OBSERVATION_KEYS, f"manifest {what}")
        scan = _inside(folder, e["scan"], f"{what} scan")
        o = ScanObservation(str(scan), _observed_state(e, folder, design, what), units=_text(e, "units", what, "auto"),
                            name=_text(e, "name", what, Path(scan).name), held_out=e.get("held_out", False) is True, **_reading(e, what))
        o.sequence(design)  # checked against the design here
        obs.append(o)
    wrt = data.get("wrt")
    regions = data.get("regions")
    if regions is not None:
        if isinstance(regions, str):
            regions = [regions]
        if not isinstance(regions, list) or not all(isinstance(r, str) for r in regions):
            raise DesignError(f"manifest {path}: \"regions\" is a list of region names (plug, cell_boundaries, "
                              f"patches:N)")
        region_faces(design, regions)  # checked here
    return obs, (check_wrt(wrt) if wrt is not None else None), regions


def calibration_markdown(result: CalibrationResult) -> str:
    """The calibration report (markdown): fitted values with standard errors, residuals, warnings."""
    lines = ["# Calibration from scans", "",
             f"{len(result.observation_names)} scan(s); {result.iterations} Gauss-Newton iteration(s), "
             f"{result.jacobians} finite-difference Jacobian(s); {'converged' if result.converged else 'stopped at the iteration limit'}.",
             "", f"Scan noise {result.noise_mm:.3f} mm, model error {result.model_error_mm:.3f} mm RMS (the residual "
             f"the model cannot follow); standard errors widened x{result.error_scale:.2f} for it.",
             "", "| parameter | start | fitted | std. error | change | z | flagged |", "|---|---|---|---|---|---|---|"]
    for label, start, value, se in _rows(result):
        se_text = "not identifiable" if not math.isfinite(se) else f"{se:.4g}"
        z = result.z.get(label)
        lines.append(f"| {label} | {start:.4g} | {value:.4g} | {se_text} | {100 * (value / start - 1):+.1f} % | "
                     f"{'-' if z is None else f'{z:.1f}'} | {'**yes**' if result.flagged(label) else 'no'} |")
    lines += ["", "Units: " + ", ".join(f"{k} {UNITS[k]}" for k in CALIBRATION_PARAMETERS), "",
              "| scan | RMS residual before (mm) | after (mm) |", "|---|---|---|"]
    for name, a, b in zip(result.observation_names, result.initial_residual_mm, result.residual_mm):
        lines.append(f"| {name} | {a:.3f} | {b:.3f} |")
    if result.held_out:
        lines += ["", "| held-out scan | RMS on the start model (mm) | calibrated (mm) | predicted |", "|---|---|---|---|"]
        lines += [f"| {n} | {a:.3f} | {b:.3f} | {'better' if b < a - 1e-3 else 'worse' if b > a + 1e-3 else 'no better'} |"
                  for n, a, b in result.held_out]
    if result.flags:
        lines += ["", "## Flagged", ""] + [f"- {f}" for f in result.flags]
    if result.realigned:
        lines += ["", "Aligned again in another turn after a first fit (docs/calibration.md, Align): "
                  + ", ".join(result.realigned)]
    if result.regions:
        lines += ["", "Regions of region_stretch (a multiplier of E t on their faces): " + ", ".join(
            f"{k} ({len(v)} faces)" for k, v in result.regions.items())]
    if bounds_reached(result):
        lines += ["", "## At a bound", ""] + [f"- {n}" for n in bounds_reached(result)]
    if result.notes:
        lines += ["", "## Not identifiable", ""] + [f"- {n}" for n in result.notes]
    if result.poorly_determined:
        lines += ["", "## Poorly determined", ""] + [f"- {n}" for n in result.poorly_determined]
    return "\n".join(lines) + "\n"


def _rows(result: CalibrationResult):
    labels = iter(result.labels)  # the fitted scalars in the values' order: name, name[i] or name[region]
    for name, value in result.values.items():
        v, s0, se = (np.atleast_1d(np.asarray(x, dtype=np.float64)) for x in
                     (value, result.start[name], result.stderr[name]))
        for i in range(len(v)):
            yield next(labels), float(s0[i]), float(v[i]), float(se[i])


UNSCANNED_COLOR = "0.25"  # faces no scan point is nearest to: dark grey, apart from coolwarm's light-grey zero


def _face_residual(m, faces: np.ndarray) -> np.ndarray:
    """(F,) the mean of each face's vertices' residuals (m) over the vertices a scan point is nearest to;
    NaN for a face none of whose vertices is."""
    vr = m.vertex_residual[faces]
    seen = np.isfinite(vr)
    with np.errstate(invalid="ignore"):
        return np.where(seen.any(axis=1), np.where(seen, vr, 0.0).sum(axis=1) / np.maximum(seen.sum(axis=1), 1),
                        np.nan)


def residual_scale_mm(result: CalibrationResult, faces: np.ndarray) -> float:
    """The colour scale's half-width (mm) shared by every scan's map: the largest face residual of the run."""
    worst = [float(np.nanmax(np.abs(f))) for f in (_face_residual(m, faces) for m in result.residuals)
             if np.any(np.isfinite(f))]
    return max(max(worst, default=0.0) * 1e3, 1e-3)


def build_residual_figure(m, faces: np.ndarray, lim_mm: float):
    """One scan's residual map as a matplotlib ``Figure``: the replayed membrane (axes in mm, model frame,
    equal scale) coloured by the signed residual (mm, + where the scan lies outside the model) on the
    symmetric scale +-``lim_mm``; faces no scan point reaches dark grey."""
    from matplotlib import colormaps  # noqa: PLC0415  (optional)
    from matplotlib.figure import Figure  # noqa: PLC0415

    fig = Figure(figsize=(5, 4.5))
    ax = fig.add_subplot(projection="3d")
    v = m.vertices * 1e3
    cmap = colormaps["coolwarm"].with_extremes(bad=UNSCANNED_COLOR)
    tri = ax.plot_trisurf(v[:, 0], v[:, 1], v[:, 2], triangles=faces, cmap=cmap, vmin=-lim_mm, vmax=lim_mm,
                          linewidth=0.1, edgecolor="0.5")
    tri.set_array(np.ma.masked_invalid(_face_residual(m, faces) * 1e3))
    fig.colorbar(tri, ax=ax, shrink=0.7, label="signed residual (mm): + scan outside the model\n"
                                                "(one scale for every scan; dark grey: not scanned)")
    ax.set_box_aspect(tuple(np.ptp(v, axis=0)))  # equal scale on the three axes: the membrane's true shape
    for set_label, axis in ((ax.set_xlabel, "x"), (ax.set_ylabel, "y"), (ax.set_zlabel, "z")):
        set_label(f"{axis} (mm, model frame)", fontsize=7)
    ax.set_title(f"{m.name}: RMS {m.rms_mm:.3f} mm")
    return fig


def write_residual_figures(result: CalibrationResult, faces: np.ndarray, out_dir) -> list[Path]:
    """``residuals_<k>.png`` per scan (``build_residual_figure``, one colour scale across the scans); none
    (an empty list) where matplotlib is not installed."""
    try:
        import matplotlib  # noqa: F401, PLC0415  (optional)
    except ImportError:
        return []
    lim = residual_scale_mm(result, faces)
    out = []
    for k, m in enumerate(result.residuals):
        fig = build_residual_figure(m, faces, lim)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        out.append(atomic_write(Path(out_dir) / f"residuals_{k}.png", buf.getvalue()))
    return out
