"""Animated USD export of a run, for content tools (usdview, Blender, Omniverse).

``export_animation(path, design, frames, times, ...)`` writes a complete scene (see
``docs/scene_format.md``; ``load_scene`` reads it back as the design) plus time samples:

- ``/Scene/Membrane.points`` (and ``extent``): one sample per frame; the rest shape stays readable
  as the default value of ``points`` and, exactly, as ``warpShape:restPoints``;
- ``/Scene/Ipams.points`` (end-face centroids, and ``extent``): one sample per frame;
- ``/Scene/Ipams.warpShape:pressure`` / ``warpShape:force`` (Pa / N, per IPAM): one sample per frame
  when given;
- ``/Scene/Membrane.primvars:warpShape:jammed`` (uniform int per face, 1 = its cell is jammed) and
  ``primvars:displayColor`` (jammed cells darker): a sample at the first frame and wherever the
  jam state changes (jamming is held between samples), plus ``warpShape:cellJammed`` (bool per cell).

Time codes are ``times * timeCodesPerSecond``; ``timeCodesPerSecond`` (and ``framesPerSecond``)
default to the frame rate of the simulated time, so content tools play the run in real time.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from ..design import Design
from ..errors import SceneError
from .scene import NS, Scene, _check_extension, _extent, _pxr, build_stage, face_colors, ipam_endpoints, \
    write_stage_atomic

__all__ = ["export_animation", "bench_usd_export"]


def _frames_rate(times: np.ndarray) -> float:
    if times.size < 2:
        return 24.0
    step = float(np.median(np.diff(times)))
    return float(f"{1.0 / step:.6g}")


def export_animation(path, design: Design, frames, times, *, ipam_pressures=None, ipam_forces=None, jammed=None,
                     targets=None, target_names=None, settings=None, time_codes_per_second: float | None = None) -> Path:
    """Write an animated stage of a run to ``path`` (``.usda`` text, ``.usdc`` / ``.usd`` binary), atomically.

    ``frames``: (F, V, 3) membrane positions in m. ``times``: (F,) strictly increasing times in s.
    ``ipam_pressures`` / ``ipam_forces``: optional (F, n_ipam) gauge Pa / axial N per frame.
    ``jammed``: optional (F, n_cell) bool jam state per frame. ``targets`` / ``target_names`` /
    ``settings``: stored as in a ``Scene``. ``time_codes_per_second``: default 1 / median frame spacing.
    Returns the path.
    """
    pxr = _pxr()
    Usd, UsdGeom, Vt, Sdf = pxr.Usd, pxr.UsdGeom, pxr.Vt, pxr.Sdf
    path = Path(path)
    _check_extension(path)
    if not isinstance(design, Design):
        raise SceneError(f"export_animation needs a ws.Design, got {type(design).__name__}")
    nv, nf = design.rest.n_vertices, design.rest.n_faces
    x = np.asarray(frames)
    if x.ndim != 3 or x.shape[1:] != (nv, 3) or x.shape[0] < 1:
        raise SceneError(f"frames must have shape (F, {nv}, 3) with F >= 1, got {x.shape}")
    x = np.ascontiguousarray(x, dtype=np.float32)
    if not np.all(np.isfinite(x)):
        f = int(np.flatnonzero(~np.isfinite(x).all(axis=(1, 2)))[0])
        raise SceneError(f"frame {f} holds non-finite positions")
    nfr = x.shape[0]
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.shape != (nfr,):
        raise SceneError(f"times must have one entry per frame ({nfr}), got shape {np.shape(times)}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise SceneError("times must be finite and strictly increasing (seconds)")

    def per_frame(a, n, what, dtype):
        if a is None:
            return None
        a = np.asarray(a)
        if a.shape != (nfr, n):
            raise SceneError(f"{what} must have shape ({nfr}, {n}) (frames, {what.split('_')[0]}s), got {a.shape}")
        if dtype is not bool and not np.all(np.isfinite(a)):
            raise SceneError(f"{what} must be finite")
        return np.ascontiguousarray(a, dtype=dtype)

    pressures = per_frame(ipam_pressures, design.n_ipams, "ipam_pressures", np.float64)
    forces = per_frame(ipam_forces, design.n_ipams, "ipam_forces", np.float64)
    jam = per_frame(jammed, design.n_cells, "cell_jammed", bool) if jammed is not None else None

    tcps = float(time_codes_per_second) if time_codes_per_second is not None else _frames_rate(t)
    if not (math.isfinite(tcps) and tcps > 0):
        raise SceneError(f"time_codes_per_second must be a positive number, got {time_codes_per_second!r}")
    codes = np.round(t * tcps, 9)
    if np.any(np.diff(codes) <= 0):
        raise SceneError("frames are closer than 1e-9 time codes apart; raise time_codes_per_second")

    scene = Scene(design=design, targets=list(targets or []), target_names=target_names, settings=settings)
    stage = build_stage(scene)
    stage.SetTimeCodesPerSecond(tcps)
    stage.SetFramesPerSecond(tcps)
    stage.SetStartTimeCode(float(codes[0]))
    stage.SetEndTimeCode(float(codes[-1]))
    tc = [Usd.TimeCode(float(c)) for c in codes]

    mesh = UsdGeom.Mesh.Get(stage, "/Scene/Membrane")
    points = mesh.GetPointsAttr()
    extent = mesh.GetExtentAttr()
    lo, hi = x.min(axis=1), x.max(axis=1)
    ext = np.ascontiguousarray(np.stack([lo, hi], axis=1))  # (F, 2, 3)
    from_np = Vt.Vec3fArray.FromNumpy
    for i in range(nfr):
        points.Set(from_np(x[i]), tc[i])
        extent.Set(from_np(ext[i]), tc[i])

    if design.n_ipams:
        curves = UsdGeom.BasisCurves.Get(stage, "/Scene/Ipams")
        ends = np.ascontiguousarray(ipam_endpoints(design, x), dtype=np.float32)  # (F, 2n, 3)
        eext = np.ascontiguousarray(np.stack([ends.min(axis=1), ends.max(axis=1)], axis=1))
        cpts, cext = curves.GetPointsAttr(), curves.GetExtentAttr()
        for i in range(nfr):
            cpts.Set(from_np(ends[i]), tc[i])
            cext.Set(from_np(eext[i]), tc[i])
        cp = curves.GetPrim()
        for name, values in (("pressure", pressures), ("force", forces)):
            if values is None:
                continue
            attr = cp.CreateAttribute(f"{NS}:{name}", Sdf.ValueTypeNames.DoubleArray, custom=True)
            for i in range(nfr):
                attr.Set(Vt.DoubleArray.FromNumpy(values[i]), tc[i])

    if jam is not None and design.n_cells:
        prim = mesh.GetPrim()
        pv = UsdGeom.PrimvarsAPI(prim)
        face_jam = pv.CreatePrimvar(f"{NS}:jammed", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform)
        cell_jam = prim.CreateAttribute(f"{NS}:cellJammed", Sdf.ValueTypeNames.BoolArray, custom=True)
        color = mesh.GetDisplayColorPrimvar()
        face_cell = design.face_cell()
        inside = face_cell >= 0
        prev = None
        for i in range(nfr):
            state = jam[i]
            if prev is not None and np.array_equal(state, prev):
                continue
            per_face = np.zeros(nf, dtype=np.int32)
            per_face[inside] = state[face_cell[inside]].astype(np.int32)
            face_jam.Set(Vt.IntArray.FromNumpy(per_face), tc[i])
            cell_jam.Set(Vt.BoolArray(state.tolist()), tc[i])
            if prev is not None:  # hold the old colour up to the frame before the change (colours interpolate)
                color.Set(Vt.Vec3fArray.FromNumpy(face_colors(design, prev)), tc[i - 1])
            color.Set(Vt.Vec3fArray.FromNumpy(face_colors(design, state)), tc[i])
            prev = state
    return write_stage_atomic(stage, path)


def bench_usd_export(frames: int = 1000, subdivisions: int = 4, formats=("usdc", "usda"), repeats: int = 3) -> dict:
    """Time ``export_animation`` of ``frames`` frames of an ``icosphere(subdivisions)`` membrane
    (Fig. 6 device: 5 IPAMs, 10 cells, pressures, forces and jam state). Returns seconds (minimum
    of ``repeats``) and file sizes per format."""
    from ..scenarios import cube_fig6_design

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
