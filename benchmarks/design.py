"""Design benchmark: wall time of the shipped design problems (oval + heart with 4 IPAMs; four targets
with 5), and the cost of the simulated placement against K, the holds tried per target in each
refinement round (each round controls K x targets screening worlds, one batch per jam plan: on a CPU
the cost grows linearly in K, on a GPU the worlds run together).

``bench_design_phases``: the default ``warp-shape design`` phase by phase (placement, refinement,
co-design and its gradients, replays and re-controls, outputs, compile, the whole process), this
checkout against a baseline commit in alternating whole processes (``design_phases``)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from warp_shape.designer import DesignSettings, design
from warp_shape.errors import DesignError
from warp_shape.io.scene_read import load_scene

from . import design_phases

__all__ = ["bench_design", "DESIGN_COLUMNS", "bench_design_phases", "PHASE_COLUMNS", "PHASE_ROWS", "checkout_root"]

DESIGN_COLUMNS = ["problem", "targets", "actuators", "placement", "K", "wall_s", "final_objective", "final_pcc",
                  "control_steps"]


def _run(name: str, device: str, placement: str, candidates: int | None) -> dict:
    sc = load_scene(name)
    opts = sc.settings["designer"]
    K = DesignSettings().candidates if candidates is None else int(candidates)
    t0 = time.perf_counter()
    res = design(sc.design.rest, sc.targets, actuators=opts["actuators"], target_names=sc.target_names,
                 cell_radius=opts["cell_radius"], device=device, placement=placement, candidates=K)
    wall = time.perf_counter() - t0
    final = res.results
    return dict(problem=name, targets=" ".join(sc.target_names), actuators=res.design.n_ipams, placement=placement,
                K=K if placement != "paper" else "-", wall_s=round(wall, 2),
                final_objective=round(float(np.mean([r.objective for r in final])), 5),
                final_pcc=" ".join(f"{r.pcc:.3f}" for r in final),
                control_steps=sum(r.control_steps for rs in res.rounds for r in rs))


def bench_design(device: str = "cpu", four_targets: bool = True, candidates=None) -> list[dict]:
    """Wall time of the default design problem and of the four-target 5-actuator problem (default
    placement), then, with ``candidates`` (a list of K), the default problem by the paper's placement,
    by the simulated placement at every K and by the greedy placement at the default K
    (final_objective: the targets' mean fit objective)."""
    rows = [_run(name, device, "simulated", None) for name in ["oval_heart"] + (["four_targets_5"] if four_targets
                                                                               else [])]
    if candidates:
        rows.append(_run("oval_heart", device, "paper", None))
        rows += [_run("oval_heart", device, "simulated", k) for k in candidates]
        rows.append(_run("oval_heart", device, "greedy", None))
    return rows


#: the phases ``bench_design_phases`` prints, in order (``design_phases``' docstring says what each holds)
PHASE_ROWS = ["process", "placement", "refinement", "codesign", "gradients", "replays", "recontrol", "outputs",
              "compile"]
PHASE_COLUMNS = ["phase", "baseline_s", "this_s", "this / baseline", "runs"]


def checkout_root() -> Path:
    """The git checkout this ``warp_shape`` is installed from (editable), or a clear error."""
    root = Path(design_phases.__file__).resolve().parent.parent
    if not (root / ".git").exists():
        raise DesignError(f"bench design --baseline needs warp_shape installed editable from a git checkout; "
                          f"{root} is not one (pip install -e <checkout>)")
    return root


def _git(root: Path, *args) -> str:
    done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise DesignError(f"git {' '.join(args)}: {done.stderr.strip() or done.stdout.strip()}")
    return done.stdout.strip()


def _probe(source: Path | None, scene: str, folder: Path, tag: str) -> dict:
    """One whole ``warp-shape design`` process with the phase clock (``design_phases``), importing the
    ``warp_shape`` of ``source`` (a baseline checkout) or this one (None); its phases, final objectives
    and the load average before it."""
    env = {k: v for k, v in os.environ.items() if k != design_phases.SOURCE_VARIABLE}
    if source is not None:  # every process of the run (its spawned workers too) imports the baseline's code
        env[design_phases.SOURCE_VARIABLE] = str(source)
        site = design_phases.write_site_hook(folder / "site")
        env["PYTHONPATH"] = os.pathsep.join([str(site)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    out, phases = folder / f"out_{tag}", folder / f"phases_{tag}.json"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    done = subprocess.run([sys.executable, design_phases.__file__, str(phases), "--", "--out", str(out), "--json",
                           *(["--scene", scene] if scene else [])], env=env, capture_output=True, text=True)
    if done.returncode != 0 or not phases.exists():
        raise DesignError(f"bench design ({tag}): warp-shape design failed (exit {done.returncode}): "
                          f"{done.stderr.strip().splitlines()[-1] if done.stderr.strip() else 'no message'}")
    report = json.loads((out / "report.json").read_text())
    shutil.rmtree(out, ignore_errors=True)
    probe = json.loads(phases.read_text())
    return dict(phases=probe["phases"], calls=probe["calls"], load=round(load, 2),
                objectives={name: f["objective"] for name, f in report["final"].items()})


def bench_design_phases(baseline: str, scene: str = "", repeats: int = 2, progress=None) -> dict:
    """The default job (``warp-shape design``; ``scene``: another shipped problem) phase by phase in
    whole processes, this checkout against the commit ``baseline`` (a temporary git worktree), in
    alternation (baseline, this, baseline, this, ...), ``repeats`` each; the best of each phase per side.
    Returns {rows: one per phase, runs: every process's phases, load averages and final objectives}."""
    root = checkout_root()
    rev = _git(root, "rev-parse", "--verify", f"{baseline}^{{commit}}")
    runs = []
    with tempfile.TemporaryDirectory(prefix="ws_bench_design_") as tmp:
        tree = Path(tmp) / "baseline"
        _git(root, "worktree", "add", "--detach", str(tree), rev)
        try:
            for k in range(repeats):
                for side, source in (("baseline", tree), ("this", None)):
                    run = _probe(source, scene, Path(tmp), f"{side}_{k}")
                    runs.append(dict(side=side, repeat=k, **run))
                    if progress is not None:
                        progress(f"{side} run {k + 1}/{repeats}: {run['phases']['process']:.1f} s "
                                 f"(load {run['load']})")
        finally:
            _git(root, "worktree", "remove", "--force", str(tree))
    rows = []
    for phase in PHASE_ROWS:
        best = {}
        for side in ("baseline", "this"):
            values = [r["phases"].get(phase) for r in runs if r["side"] == side]
            values = [v for v in values if v is not None]
            best[side] = min(values) if values else None
        ratio = (round(best["this"] / best["baseline"], 2) if best["this"] is not None and best["baseline"] else "-")
        rows.append({"phase": phase, "baseline_s": best["baseline"] if best["baseline"] is not None else "-",
                     "this_s": best["this"] if best["this"] is not None else "-", "this / baseline": ratio,
                     "runs": " / ".join(f"{r['phases'].get(phase)}" for r in runs)})
    return dict(baseline=rev, scene=scene or "oval_heart", repeats=repeats, rows=rows, runs=runs)
