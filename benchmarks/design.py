"""Design benchmark: wall time of the shipped design problems (oval + heart with 4 IPAMs; four targets
with 5), and the cost of the simulated placement against K, the holds tried per target in each
refinement round (each round controls K x targets screening worlds, one batch per jam plan: on a CPU
the cost grows linearly in K, on a GPU the worlds run together)."""

from __future__ import annotations

import time

import numpy as np

from warp_shape.designer import DesignSettings, design
from warp_shape.io.scene_read import load_scene

__all__ = ["bench_design", "DESIGN_COLUMNS"]

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
