"""The sweep's results table: ``results.csv`` and ``results.json``, rewritten atomically as each run finishes.

One row per run. Columns: ``run_id``, ``targets`` (space-separated names), ``actuators``, the swept
parameters, ``objective`` (the fit objective of the final design, mean over the run's targets),
``pcc_<target>``, ``mare_<target>_m``, ``mpre_<target>_pct`` for every target of the sweep (empty
where a run does not have that target), ``wall_s``, ``status`` (``ok`` or ``error``), ``error`` and
``out_dir`` (the run's folder, as ``warp-shape design`` writes it). Each rewrite goes through a
temporary file and a rename, so a reader (or a crash) never sees half a row. ``results.json`` also
holds the sweep's description, so a rerun into the same folder can tell it is the same sweep.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

from ..errors import read_input_file
from ..io.atomic import atomic_write, hold_lock, manifest_problems, release_lock
from .params import SweepError

__all__ = ["ResultsTable", "columns_for", "place_outputs"]

TAIL = ["wall_s", "status", "error", "out_dir"]


def columns_for(target_names, swept_names) -> list[str]:
    """The column order of a sweep over ``target_names`` with ``swept_names`` parameters."""
    cols = ["run_id", "targets", "actuators"] + [n for n in swept_names if n != "actuators"] + ["objective"]
    cols += [f"pcc_{t}" for t in target_names]
    cols += [f"mare_{t}_m" for t in target_names]
    cols += [f"mpre_{t}_pct" for t in target_names]
    return cols + TAIL


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)  # shortest text that reads back to the same float
    return str(value)


class ResultsTable:
    """The rows of a sweep folder, keyed by run id; ``put`` stores a row and rewrites both files."""

    def __init__(self, folder, columns: list[str], description: dict):
        self.folder = Path(folder)
        self.columns = list(columns)
        self.description = dict(description)
        self.rows: dict[str, dict] = {}

    @property
    def csv_path(self) -> Path:
        return self.folder / "results.csv"

    @property
    def json_path(self) -> Path:
        return self.folder / "results.json"

    def load(self) -> "ResultsTable":
        """Read the rows a previous run of the same sweep left; a different sweep in the folder is an error."""
        if not self.json_path.exists():
            if self.csv_path.exists():
                raise SweepError(f"{self.csv_path} exists without results.json: not a sweep folder of this "
                                 f"version; use another --out")
            return self
        raw = read_input_file(self.json_path, "sweep results file", SweepError)  # a regular file, bounded
        try:
            data = json.loads(raw)
            rows = [r for r in data.get("rows", []) if isinstance(r.get("run_id"), str)]
        except (OSError, ValueError, AttributeError, TypeError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) else f"not a sweep's results table: {exc}"
            raise SweepError(f"{self.json_path} cannot be read ({reason}); give --restart to discard the folder's "
                             f"results and run every run again, or use another --out") from None
        old = data.get("sweep", {})
        if old != json.loads(json.dumps(self.description)):
            changed = sorted(k for k in set(old) | set(self.description) if old.get(k) != self.description.get(k))
            raise SweepError(f"{self.folder} holds a different sweep (differs in {', '.join(changed)}); "
                             f"use another --out, or --restart to discard its results")
        self.rows = {r["run_id"]: r for r in rows}
        return self

    def lock(self) -> None:
        """Hold ``.sweep.lock`` in the folder while this process runs the sweep: a second sweep into the
        same folder is refused (the lock goes with the process, even when it is killed)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock_fd = hold_lock(self.folder / ".sweep.lock",
                                  lambda holder: SweepError(f"another sweep (process {holder}) is writing to "
                                                            f"{self.folder}; wait for it to finish or give another --out"))

    def unlock(self) -> None:
        if getattr(self, "_lock_fd", None) is not None:
            release_lock(self.folder / ".sweep.lock", self._lock_fd)
            self._lock_fd = None

    def finished(self, run_id: str) -> bool:
        """True when the run has an ``ok`` row and its output folder holds every file its manifest lists,
        unchanged (a deleted or edited ``design.usda`` makes the run run again)."""
        row = self.rows.get(run_id)
        if not (row and row.get("status") == "ok" and row.get("out_dir")):
            return False
        out = self.folder / row["out_dir"]
        return out.is_dir() and not manifest_problems(out)

    def put(self, row: dict, order: list[str] | None = None) -> None:
        """Store a row (replacing the run's previous one) and rewrite ``results.json`` then ``results.csv``."""
        self.rows[row["run_id"]] = row
        if order is not None:
            rank = {rid: i for i, rid in enumerate(order)}
            self.rows = dict(sorted(self.rows.items(), key=lambda kv: rank.get(kv[0], len(rank))))
        self.write()

    def write(self) -> None:
        rows = list(self.rows.values())
        data = dict(sweep=self.description, columns=self.columns, rows=rows)
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write(self.json_path, json.dumps(data, indent=1) + "\n")
        atomic_write(self.csv_path, self.csv_text())

    def csv_text(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.columns)
        for row in self.rows.values():
            w.writerow([_cell(row.get(c)) for c in self.columns])
        return buf.getvalue()


def place_outputs(folder: Path, run_id: str, files: dict) -> str:
    """Write a run's files into ``runs/<run_id>/`` (through a temporary folder and a rename, so the
    folder is whole or absent); returns the folder relative to the sweep folder."""
    runs = Path(folder) / "runs"
    final = runs / run_id
    tmp = runs / f".{run_id}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    for name, data in files.items():
        path = tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    tmp.mkdir(parents=True, exist_ok=True)
    if final.exists():
        shutil.rmtree(final)
    tmp.rename(final)
    return str(final.relative_to(folder))
