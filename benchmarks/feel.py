"""Stiffness-map benchmark: a 64-point fingertip map of the Fig. 6 device's controlled cube (one press per
world of one batch) beside the control run that made the state, wall time side by side in one process."""

from __future__ import annotations

import time

import numpy as np

from warp_shape.controller import control
from warp_shape.feel import feel_map, press, pressable_directions, stiffness_map
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulator import Simulator
from warp_shape.targets import target

__all__ = ["bench_feel", "FEEL_COLUMNS", "stiffness_by_pressure", "PRESSURE_COLUMNS"]

PRESSURE_COLUMNS = ["air", "pressure_pa", "top_n_per_mm", "top_jammed_n_per_mm", "side_n_per_mm"]
FEEL_COLUMNS = ["vertices", "method", "control_s", "points", "depth_mm", "map_s", "ratio", "min_n_per_mm",
                "median_n_per_mm", "max_n_per_mm"]


def bench_feel(device: str = "cpu", points: int = 64, depth: float = 0.002, method: str = "paper") -> list[dict]:
    """One row: the control run's wall time, the map's (``points`` directions of a Fibonacci lattice, those
    near the plug left out) and their ratio, with the map's spread."""
    design = cube_fig6_design()
    t0 = time.perf_counter()
    res = control(design, target("cube"), device=device, method=method)
    control_s = time.perf_counter() - t0
    count = points
    dirs = pressable_directions(res, count)
    while len(dirs) < points:  # the plug's directions left out: ask for a few more
        count += points - len(dirs)
        dirs = pressable_directions(res, count)
    t0 = time.perf_counter()
    fm = feel_map(res, dirs[:points], depth)
    map_s = time.perf_counter() - t0
    k = fm.stiffness / 1000.0
    return [dict(vertices=design.rest.n_vertices, method=method, control_s=round(control_s, 2), points=len(k),
                 depth_mm=depth * 1e3, map_s=round(map_s, 2), ratio=round(map_s / control_s, 3),
                 min_n_per_mm=round(float(k.min()), 4), median_n_per_mm=round(float(np.median(k)), 4),
                 max_n_per_mm=round(float(k.max()), 4))]


def stiffness_by_pressure(airs=(1.1, 1.2, 1.3, 1.4), depth: float = 0.002, device: str = "cpu") -> list[dict]:
    """The Fig. 6 device inflated by each air factor (IPAMs at rest), settled: the fingertip's stiffness at
    ``depth`` on the top (free and with its cell jammed) and on the +x side, with the chamber's gauge pressure."""
    design = cube_fig6_design()
    top_cell = int(design.face_cell()[design.ipams[4].face_a])
    rows = []
    for air in airs:
        sim = Simulator(design, device=device, precision="float64")
        sim.air_moles *= air
        sim.settle_static()
        k = stiffness_map(sim, [(0, 0, 1), (1, 0, 0.1)], depth=depth)
        sim.jam(top_cell)
        jammed = press(sim, (0, 0, 1), [depth])
        rows.append(dict(air=air, pressure_pa=round(float(jammed.pressure[0]), 1),
                         top_n_per_mm=round(float(k[0]) / 1e3, 4),
                         top_jammed_n_per_mm=round(float(jammed.stiffness[0]) / 1e3, 4),
                         side_n_per_mm=round(float(k[1]) / 1e3, 4)))
    return rows
