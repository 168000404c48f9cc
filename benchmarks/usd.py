"""USD export benchmark: seconds and file size of an animated export, per file format."""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from warp_shape.io.usd_animation import export_animation
from warp_shape.scenarios import cube_fig6_design

__all__ = ["bench_usd_export"]


def bench_usd_export(frames: int = 1000, subdivisions: int = 4, formats=("usdc", "usda"), repeats: int = 3) -> dict:
    """Time ``export_animation`` of ``frames`` frames of an ``icosphere(subdivisions)`` membrane
    (Fig. 6 device: 5 IPAMs, 10 cells, pressures, forces and jam state). Returns seconds (minimum
    of ``repeats``) and file sizes per format."""
    d = cube_fig6_design(subdivisions=subdivisions)
    rest = d.rest.vertices
    t = np.arange(frames) * 1e-3
    s = 1.0 + 0.1 * np.sin(2 * np.pi * 5.0 * t)
    rng = np.random.default_rng(0)
    x = rest[None] * s[:, None, None] + rng.normal(0.0, 1e-4, (frames,) + rest.shape)
    p = np.outer(np.sin(t), np.full(d.n_ipams, 1e5))
    jam = np.zeros((frames, d.n_cells), dtype=bool)
    jam[frames // 2:, 0] = True
    out = {"frames": int(frames), "vertices": int(rest.shape[0]), "faces": int(d.rest.n_faces),
           "ipams": d.n_ipams, "cells": d.n_cells}
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in formats:
            path = Path(tmp) / f"bench.{fmt}"
            best = math.inf
            for _ in range(max(1, int(repeats))):
                t0 = time.perf_counter()
                export_animation(path, d, x, t, ipam_pressures=p, ipam_forces=p * 1e-4, jammed=jam)
                best = min(best, time.perf_counter() - t0)
            out[f"{fmt}_s"] = best
            out[f"{fmt}_frames_per_s"] = frames / best
            out[f"{fmt}_bytes"] = path.stat().st_size
    return out
