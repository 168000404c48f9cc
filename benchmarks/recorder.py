"""Rerun recorder benchmark: the wall-time cost of logging a control run to a recording."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from warp_shape.controller import control
from warp_shape.io.recorder import Recorder
from warp_shape.scenarios import cube_fig6_design
from warp_shape.targets import target

__all__ = ["bench_recorder"]


def bench_recorder(subdivisions: int = 2, max_steps: int = 30, repeats: int = 3, device: str = "cpu",
                   out_dir=None) -> dict:
    """Wall time of a short control run (the Fig. 6 device driven to the cube by the paper's law)
    without a recorder, with one logging every control step, and with ``every=5``: minimum of ``repeats``, measured
    side by side; plus the recording sizes. (That a recorder adds no Warp launch is a test:
    tests/test_rerun.py.)"""
    d = cube_fig6_design(subdivisions=subdivisions)
    cube = target("cube")
    kw = dict(device=device, max_steps=max_steps, target_name="cube", method="paper")
    control(d, cube, **kw)  # warm up: kernels loaded, caches filled
    tmp = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="bench_recorder_"))
    tmp.mkdir(parents=True, exist_ok=True)
    times = {"none": [], "every1": [], "every5": []}
    sizes = {}
    steps = 0
    for _ in range(repeats):
        for key in times:
            rec = None if key == "none" else Recorder(tmp / f"{key}.rrd", every=1 if key == "every1" else 5)
            t0 = time.perf_counter()
            res = control(d, cube, recorder=rec, **kw)
            if rec is not None:
                rec.close()
            times[key].append(time.perf_counter() - t0)
            steps = res.control_steps + 1
            if rec is not None:
                sizes[key] = os.path.getsize(rec.path)
    best = {k: min(v) for k, v in times.items()}
    return dict(vertices=d.rest.n_vertices, ipams=d.n_ipams, cells=d.n_cells, control_steps=steps, repeats=repeats,
                wall_s_no_recorder=best["none"], wall_s_every1=best["every1"], wall_s_every5=best["every5"],
                ratio_every1=best["every1"] / best["none"], ratio_every5=best["every5"] / best["none"],
                ms_per_logged_step_every1=1e3 * (best["every1"] - best["none"]) / steps,
                rrd_bytes_every1=sizes.get("every1"), rrd_bytes_every5=sizes.get("every5"))
