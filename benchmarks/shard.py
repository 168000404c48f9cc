"""Sharding benchmark: the same commands on 1 worker and on N, side by side in one run.

``python -m warp_shape.benchmarks.shard [--workers 1 2] [--repeats 2] [--cases design control]``
runs, for every repeat, every case with every worker count (the order of the counts alternates
between repeats, so a load that changes during the run falls on both alike):
- ``design``: ``warp-shape design`` (the default problem: oval + heart, 4 IPAMs, 642 vertices);
- ``control``: ``warp-shape control --targets oval pear heart cube`` (the Fig. 6 device, 642
  vertices, driven to four targets by the model-based controller: one batch of four worlds).
Each is the real command in its own process (start-up and outputs included), timed from outside;
the table gives the wall time of every run, the speed-up of the means and the largest difference of
the final objectives against 1 worker. The results go to ``bench_shard.json`` in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from warp_shape.cli.options import resolve_design_and_targets
from warp_shape.controller import control_many
from warp_shape.controller.shard import worker_pool
from warp_shape.designer import design
from warp_shape.designer.run_settings import RunSettings
from warp_shape.io.scene_read import load_scene

__all__ = ["bench_shard", "critical_path", "makespan", "CASES"]

CASES = {
    "design": ["design"],
    "control": ["control", "--targets", "oval", "pear", "heart", "cube"],
}


def _objectives(case: str, out: Path) -> dict:
    """{target: final objective} of a finished run's outputs."""
    if case == "design":
        report = json.loads((out / "report.json").read_text())
        return {n: report["final"][n]["objective"] for n in report["targets"]}
    return {p.stem[len("control_"):]: json.loads(p.read_text())["objective"]
            for p in sorted(out.glob("control_*.json"))}


def _run(case: str, workers: int, folder: Path) -> dict:
    out = folder / f"{case}_{workers}"
    env = dict(os.environ)
    env.pop("WARP_SHAPE_WORKERS", None)
    cmd = [sys.executable, "-m", "warp_shape.cli", *CASES[case], "--workers", str(workers), "--out", str(out)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)  # the command and its workers
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return dict(case=case, workers=workers, wall_s=round(wall, 2), cpu_s=round(cpu, 2),
                objectives=_objectives(case, out),
                load=round(os.getloadavg()[0], 2))


def bench_shard(workers=(1, 2), repeats: int = 2, cases=("design", "control")) -> dict:
    """Every case at every worker count, ``repeats`` times (module docstring); the runs and a summary."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="warp_shape_shard_") as tmp:
        for r in range(repeats):
            order = list(workers) if r % 2 == 0 else list(workers)[::-1]
            for case in cases:
                for w in order:
                    runs.append(dict(_run(case, w, Path(tmp)), repeat=r))
                    x = runs[-1]
                    print(f"  {case:8s} workers {w}: {x['wall_s']:7.1f} s wall, {x['cpu_s']:7.1f} s CPU "
                          f"(load {x['load']})", flush=True)
    summary = []
    for case in cases:
        base = [x for x in runs if x["case"] == case and x["workers"] == workers[0]]
        for w in workers:
            mine = [x for x in runs if x["case"] == case and x["workers"] == w]
            diff = max(abs(a["objectives"][k] - b["objectives"][k])
                       for a, b in zip(mine, base) for k in a["objectives"])
            summary.append(dict(case=case, workers=w, wall_s=[x["wall_s"] for x in mine],
                                cpu_s=round(float(np.mean([x["cpu_s"] for x in mine])), 2),
                                mean_s=round(float(np.mean([x["wall_s"] for x in mine])), 2),
                                speedup=round(float(np.mean([x["wall_s"] for x in base]) /
                                                    np.mean([x["wall_s"] for x in mine])), 2),
                                max_objective_diff=float(diff)))
    return dict(runs=runs, summary=summary, cpu_count=os.cpu_count())


def makespan(seconds: list, workers: int) -> float:
    """The time ``workers`` idle cores take for jobs of these CPU times, each job to the next free core
    in order (as ``WorkerPool.run`` hands them out)."""
    free = [0.0] * workers
    for t in seconds:
        k = int(np.argmin(free))
        free[k] += t
    return max(free)


def _problem(case: str):
    """``run(workers)`` of the case in this process, as its command runs it."""
    if case == "design":
        scene = load_scene("oval_heart")
        run = RunSettings.from_groups(scene.settings, material=scene.design.material if scene.design else None)
        return lambda w: design(scene.base_mesh(None), scene.targets, actuators=run.actuators,
                                target_names=scene.target_names, settings=run.designer.replace(workers=w),
                                control_settings=run.control, material=run.material).results
    d, named, groups = resolve_design_and_targets(None, CASES["control"][2:], "auto")
    settings = RunSettings.from_groups(groups).control
    return lambda w: control_many(d, [t for _, t in named], settings=settings.replace(workers=w))


def critical_path(case: str, workers: int = 2) -> dict:
    """The case in this process on one core and on a pool of ``workers``, with every job's CPU time:
    the wall time an idle machine would take (the caller's CPU time, which holds every serial part, plus
    each batch's makespan on ``workers`` cores, the workers' start-up left out: it overlaps the set-up)."""
    run = _problem(case)
    c0, t0 = time.process_time(), time.perf_counter()
    one = run(1)
    one_cpu, one_wall = time.process_time() - c0, time.perf_counter() - t0
    with worker_pool(workers) as pool:
        pool.start()
        time.sleep(5.0)  # the workers' start-up, kept out of the caller's CPU time
        c0, t0 = time.process_time(), time.perf_counter()
        many = run(workers)
        caller, wall = time.process_time() - c0, time.perf_counter() - t0
        batches = pool.job_seconds
    model = caller + sum(makespan(b, workers) for b in batches)
    return dict(case=case, workers=workers, one_cpu_s=round(one_cpu, 2), one_wall_s=round(one_wall, 2),
                wall_s=round(wall, 2), caller_cpu_s=round(caller, 2), batches=len(batches),
                jobs=sum(len(b) for b in batches), job_cpu_s=round(sum(map(sum, batches)), 2),
                idle_wall_s=round(model, 2), idle_speedup=round(one_cpu / model, 2),
                max_objective_diff=float(max(abs(a.objective - b.objective) for a, b in zip(one, many))))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    p.add_argument("--out", default="out/bench")
    p.add_argument("--critical-path", action="store_true",
                   help="instead: each case in this process, one core against a pool, with every job's CPU time")
    args = p.parse_args(argv)
    if args.critical_path:
        rows = [critical_path(c, max(args.workers)) for c in args.cases]
        for r in rows:
            print(json.dumps(r))
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "bench_shard_critical_path.json").write_text(json.dumps(rows, indent=2))
        return 0
    res = bench_shard(tuple(args.workers), args.repeats, tuple(args.cases))
    print(f"{'case':10s}{'workers':>8s}  {'wall s (each run)':28s}{'mean s':>8s}{'speed-up':>10s}{'CPU s':>8s}"
          f"{'max |d obj|':>13s}")
    for s in res["summary"]:
        runs = " ".join(f"{v:.1f}" for v in s["wall_s"])
        print(f"{s['case']:10s}{s['workers']:8d}  {runs:28s}{s['mean_s']:8.1f}{s['speedup']:10.2f}{s['cpu_s']:8.1f}"
              f"{s['max_objective_diff']:13.2e}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_shard.json").write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
