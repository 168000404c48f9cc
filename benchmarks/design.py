"""Design benchmark: wall time of the shipped design problems (oval + heart with 4 IPAMs; four targets with 5)."""

from __future__ import annotations

import time

from warp_shape.designer import design
from warp_shape.io.scene_read import load_scene

__all__ = ["bench_design"]


def bench_design(device: str = "cpu", four_targets: bool = True) -> list[dict]:
    """Wall time of the default design problem and of the four-target 5-actuator problem."""
    rows = []
    names = ["oval_heart"] + (["four_targets_5"] if four_targets else [])
    for name in names:
        sc = load_scene(name)
        opts = sc.settings["designer"]
        t0 = time.perf_counter()
        res = design(sc.design.rest, sc.targets, actuators=opts["actuators"], target_names=sc.target_names,
                     cell_radius=opts["cell_radius"], device=device)
        wall = time.perf_counter() - t0
        rows.append(dict(problem=name, targets=" ".join(sc.target_names), actuators=opts["actuators"],
                         wall_s=round(wall, 2), final_pcc=" ".join(f"{v:.3f}" for v in res.pcc_by_round[-1]),
                         control_steps=sum(r.control_steps for rs in res.rounds for r in rs)))
    return rows
