"""``sweep(...)``: plan the runs, skip the finished ones, run the rest, stream the rows, summarise."""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .backends import BACKENDS, require_ray, run_ray, run_serial
from .params import Param, SweepError, check_values, parse_param
from .plan import grid_plan, load_problem, subsets_plan
from .results import ResultsTable, columns_for, place_outputs
from .run import execute
from .summary import write_summary

__all__ = ["sweep", "SweepResult", "KINDS"]

KINDS = ("subsets", "grid")


@dataclass
class SweepResult:
    """What a sweep did: its folder, every row (finished now or before), how many ran now and were
    skipped, the wall time, Ray's start-up time (0 for the serial backend) and the summary files."""

    folder: Path
    rows: list
    ran: int
    skipped: int
    wall_s: float
    startup_s: float = 0.0
    summary: list = field(default_factory=list)

    @property
    def failed(self) -> list:
        """Rows of runs that did not finish."""
        return [r for r in self.rows if r.get("status") != "ok"]


def _params(params) -> list[Param]:
    """``["actuators=5,10"]`` or ``{"actuators": [5, 10]}`` -> checked ``Param`` list."""
    if params is None:
        return []
    if isinstance(params, dict):
        return [check_values(k, list(v) if isinstance(v, (list, tuple)) else [v]) for k, v in params.items()]
    return [p if isinstance(p, Param) else parse_param(p) for p in params]


def _progress(total: int, done: int, show):
    """A tqdm bar (runs done / total, ETA) on a terminal; None when quiet or tqdm is missing."""
    if show is None:
        show = sys.stderr.isatty()
    if not show:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, initial=done, unit="run", desc="sweep", file=sys.stderr, dynamic_ncols=True)


def _description(kind, problem, params: list[Param], device) -> dict:
    return dict(kind=kind, scene=problem.scene, targets=[n for n, _ in problem.targets],
                fixed={k: v for k, v in problem.fixed.items()},
                params={p.name: list(p.values) for p in params}, device=device)


def _check_folder(out: Path) -> None:
    """The sweep folder, or the nearest existing folder above it, must be a folder (not a file)."""
    probe = out
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        where = "" if probe == out else f": {probe} is a file"
        raise SweepError(f"--out {out}{where or ' is a file'}, not a folder; give the sweep a folder (new, or "
                         f"holding an earlier sweep to resume)")


def sweep(kind: str = "subsets", scene: str | None = None, *, targets=None, actuators: int | None = None,
          params=None, fixed: dict | None = None, out="sweep", backend: str = "ray", workers: int | None = None,
          address: str | None = None, device: str = "cpu", retries: int = 1, restart: bool = False,
          progress: bool | None = None, run_fn=None) -> SweepResult:
    """Run many designs and collect their fit in ``out/results.csv`` (and ``results.json``).

    ``kind="subsets"``: every non-empty subset of ``targets`` (the paper's Fig. 11); ``kind="grid"``:
    the product of ``params`` values (``{"actuators": [5, 10, 20]}`` or ``["actuators=5,10,20"]``;
    any designer, controller, simulation or material setting, ``subdivisions`` of the base mesh).
    ``scene``: the design problem (default ``oval_heart``, as ``warp-shape design``); ``fixed``:
    settings applied to every run (``{"method": "paper"}``). ``backend``: ``"ray"`` (a local instance,
    or the cluster at ``address``; ``workers`` runs at a time) or ``"serial"``. Rows stream into the
    folder as runs finish; a rerun skips finished runs (``restart=True`` discards them); a failed run
    records its error. ``run_fn(task) -> (row, files)`` replaces the design run (testing).
    """
    if kind not in KINDS:
        raise SweepError(f"unknown sweep kind {kind!r}; choose one of {list(KINDS)}")
    if backend not in BACKENDS:
        raise SweepError(f"unknown backend {backend!r}; choose one of {list(BACKENDS)}")
    if workers is not None and workers < 1:
        raise SweepError(f"workers must be >= 1, got {workers}")
    _check_folder(Path(out))
    if backend == "ray":
        require_ray()  # before any work: say how to install it
    fixed = dict(fixed or {})
    if actuators is not None:
        fixed["actuators"] = actuators
    plist = _params(params)
    problem = load_problem(scene, targets, fixed)
    tasks = subsets_plan(problem, device, plist) if kind == "subsets" else grid_plan(problem, plist, device)
    if len({t.run_id for t in tasks}) != len(tasks):
        raise SweepError("two runs of this sweep would share a folder name; give distinct values")
    return _execute(kind, problem, plist, tasks, Path(out), backend=backend, workers=workers, address=address,
                    device=device, retries=retries, restart=restart, progress=progress, run_fn=run_fn)


def _execute(kind, problem, plist, tasks, folder: Path, *, backend, workers, address, device, retries, restart,
             progress, run_fn) -> SweepResult:
    names = [n for n, _ in problem.targets]
    swept = [p.name for p in plist]
    table = ResultsTable(folder, columns_for(names, swept), _description(kind, problem, plist, device))
    table.lock()
    try:
        return _run_locked(table, kind, names, swept, tasks, folder, backend=backend, workers=workers,
                           address=address, device=device, retries=retries, restart=restart, progress=progress,
                           run_fn=run_fn)
    finally:
        table.unlock()


def _run_locked(table, kind, names, swept, tasks, folder: Path, *, backend, workers, address, device, retries,
                restart, progress, run_fn) -> SweepResult:
    if restart:
        for stale in ("results.json", "results.csv", "runs"):
            p = folder / stale
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    table.load()
    todo = [t for t in tasks if not table.finished(t.run_id)]
    order = [t.run_id for t in tasks]
    bar = _progress(len(tasks), len(tasks) - len(todo), progress)

    def on_done(task, row, files):
        row["out_dir"] = place_outputs(folder, task.run_id, files) if row.get("status") == "ok" else ""
        table.put(row, order)
        if bar is not None:
            bar.update(1)

    if backend == "ray" and str(device).startswith("cuda"):
        for task in todo:  # Ray gives each task one GPU, visible to it as cuda:0
            task.device = "cuda"
    t0 = time.perf_counter()
    startup = 0.0
    try:
        if backend == "serial":
            run_serial(todo, run_fn or execute, on_done)
        elif todo:
            startup = run_ray(todo, run_fn or execute, on_done, workers=workers, address=address, retries=retries,
                              gpus_per_run=1.0 if str(device).startswith("cuda") else 0.0)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    table.write()
    rows = [table.rows[rid] for rid in order if rid in table.rows]
    summary = write_summary(folder, rows, names, swept, kind)
    return SweepResult(folder=folder, rows=rows, ran=len(todo), skipped=len(tasks) - len(todo), wall_s=wall,
                       startup_s=startup, summary=summary)
