"""One run of a sweep: the design ``warp-shape design`` runs, its outputs, and the run's results row.

``execute(task)`` runs in the driver (serial backend) or in a Ray worker: it designs, writes every
output with ``io.outputs.write_design_outputs`` (the code the ``design`` command uses) into a fresh
temporary folder, and returns the row and the files' bytes, so the driver places them in the sweep's
folder whichever machine the run ran on. A run that fails returns its error in the row.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np
import warp as wp

from ..designer import DesignSettings, design
from ..designer.run_settings import RunSettings
from ..io.atomic import StagedFolder, write_json
from ..io.outputs import is_run_output, record_round, write_design_outputs
from ..material import Material
from .plan import RunTask

__all__ = ["execute", "row_of", "error_row", "read_outputs"]


def _settings(task: RunTask) -> tuple[RunSettings, dict]:
    """The run's RunSettings (the scene's groups and material, the fixed and the swept values) and
    its other design() keywords."""
    s = task.settings
    known = DesignSettings.__dataclass_fields__
    run = RunSettings.from_groups({"simulation": s.get("simulation", {}), "controller": s.get("controller", {}),
                                   "designer": {k: v for k, v in s.get("designer", {}).items() if k in known}},
                                  material=Material(**s.get("material", {})))
    return run, dict(s.get("design", {}))


def _head(task: RunTask) -> dict:
    """The columns naming a run: id, targets, actuator count and the swept values."""
    row = dict(run_id=task.run_id, targets=" ".join(task.target_names), actuators=task.actuators)
    row.update({k: v for k, v in task.swept.items() if k != "actuators"})
    return row


def row_of(task: RunTask, result, wall: float) -> dict:
    """A finished run's row: the mean fit objective over its targets, per target PCC, MARE (m) and
    MPRE (%) of the final design."""
    row = _head(task)
    finals = result.results
    row["objective"] = float(np.mean([r.objective for r in finals]))
    for name, r in zip(task.target_names, finals):
        row[f"pcc_{name}"] = float(r.pcc)
        row[f"mare_{name}_m"] = float(r.mare)
        row[f"mpre_{name}_pct"] = float(r.mpre)
    row.update(wall_s=round(wall, 3), status="ok", error="")
    return row


def error_row(task: RunTask, error: str, wall: float = 0.0) -> dict:
    """The row of a run that failed: its error (type and message) and no numbers."""
    row = _head(task)
    row.update(wall_s=round(wall, 3), status="error", error=" ".join(str(error).split())[:500])
    return row


def read_outputs(folder: Path) -> dict:
    """{relative path: bytes} of every file under ``folder``."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _outputs(task: RunTask, result, records: list, wall: float) -> dict:
    """Every file ``warp-shape design`` leaves for this result (rounds.json, the design outputs and the
    manifest), written in a temporary folder; {relative path: bytes}."""
    with tempfile.TemporaryDirectory(prefix="warp_shape_run_") as tmp:
        staged = StagedFolder(Path(tmp) / "run", owned=is_run_output)
        write_json(staged.path / "rounds.json", dict(targets=list(task.target_names), rounds=list(records)))
        write_design_outputs(result, staged.path, marker_height=task.marker_height,
                             layer_thickness=task.layer_thickness, kept=["rounds.json", "manifest.json"],
                             extra_report=dict(complete=True, wall_seconds=wall, device=task.device,
                                               sweep_run=task.run_id, swept=task.swept))
        return read_outputs(staged.commit(True, command="sweep"))


def execute(task: RunTask) -> tuple[dict, dict]:
    """Design, write the outputs (as ``warp-shape design``), return (row, {file: bytes}); never raises
    for a failed design: the row carries the error."""
    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    t0 = time.perf_counter()
    records: list = []

    def on_round(i, design_i, results):  # as the design command records each finished round
        record_round(records, i, design_i, results, task.target_names)

    try:
        run, keywords = _settings(task)
        if run.designer.workers == 0:  # "every core": the sweep runs one design per core already
            run = dataclasses.replace(run, designer=run.designer.replace(workers=1))
        result = design(task.base, task.targets, actuators=task.actuators, device=task.device,
                        target_names=task.target_names, settings=run.designer, control_settings=run.control,
                        material=run.material, on_round=on_round, **keywords)
        files = _outputs(task, result, records, time.perf_counter() - t0)
        return row_of(task, result, time.perf_counter() - t0), files
    except Exception as exc:  # a failing run is recorded, the sweep goes on
        detail = f"{type(exc).__name__}: {exc}"
        if not type(exc).__module__.startswith("warp_shape"):
            detail += " | " + traceback.format_exc(limit=-1).strip().splitlines()[-2].strip()
        return error_row(task, detail, time.perf_counter() - t0), {}
