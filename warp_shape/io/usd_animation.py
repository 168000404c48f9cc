"""Write a simulated run as an animated USD scene, for content tools (usdview, Blender, Omniverse).

``export_animation(path, design, frames, times, ...)`` writes a complete scene (see
``docs/scene_format.md``; ``load_scene`` reads it back as the design) plus time samples:

- ``/Scene/Membrane.points`` (and ``extent``): one sample per frame; the rest shape stays readable
  as the default value of ``points`` and, exactly, as ``warpShape:restPoints``;
- ``/Scene/Ipams.points`` (end-face centroids, and ``extent``): one sample per frame, as for the
  curves of every other actuator family on its prim (``ActuatorFamily.curve_ends``);
- ``/Scene/Ipams.warpShape:pressure`` / ``warpShape:force`` (Pa / N, per IPAM): one sample per frame
  when given;
- ``/Scene/Membrane.primvars:warpShape:jammed`` (uniform int per face, 1 = its cell is jammed) and
  ``primvars:displayColor`` (jammed cells darker): a sample at the first frame and wherever the
  jam state changes (jamming is held between samples), plus ``warpShape:cellJammed`` (bool per cell).

Time codes: the stage's ``timeCodesPerSecond`` and ``framesPerSecond`` are both ``FRAME_RATE``
(24), the rate content tools play at, so a tool that applies only one of them still plays in real
time. Frame k's time code is ``24 * (times[k] - times[0])``: the stage starts at 0 and ends at
24 x the sequence's duration. ``duration`` stretches the times to last that many seconds.
``playback_times`` gives a control result's times either as simulated or on the lab's clock of its
valve schedule (``io.valve``: the pump's flow and the valves' slew limits, on the CSV's grid), the
default for the ``actuation_<target>.usdc`` files, so a sequence plays as long as the lab takes and
each frame's time is a row of the valve CSV.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..force_family import families
from ..display import Design
from ..errors import SceneError
from .scene_schema import IPAMS, MEMBRANE, NS, ROOT_NAME, Scene
from .scene_write import build_stage, write_stage_atomic
from .usd_common import FRAME_RATE, check_extension, face_colors, load_pxr
from .valve import row_times

__all__ = ["export_animation", "playback_times", "PLAYBACKS"]

#: how a control result's sequence is timed in its animation (``playback_times``)
PLAYBACKS = ("valve", "simulated")


def playback_times(result, playback: str = "valve", timing=None) -> np.ndarray:
    """(n_rows,) seconds from 0 of each control step of ``result``: ``"valve"`` the lab's clock of
    the valve CSV (``io.valve.row_times`` under ``timing``, default ``ValveTiming()``),
    ``"simulated"`` the simulator's clock."""
    if playback not in PLAYBACKS:
        raise SceneError(f"playback must be one of {', '.join(PLAYBACKS)}, got {playback!r}")
    if playback == "simulated":
        t = np.asarray(result.history["time"], dtype=np.float64)
        return t - t[0]
    return row_times(result, timing)


def export_animation(path, design: Design, frames, times, *, ipam_pressures=None, ipam_forces=None, jammed=None,
                     targets=None, target_names=None, settings=None, time_codes_per_second: float = FRAME_RATE,
                     duration: float | None = None, playback: dict | None = None) -> Path:
    """Write an animated stage of a run to ``path`` (``.usda`` text, ``.usdc`` / ``.usd`` binary), atomically.

    ``frames``: (F, V, 3) membrane positions in m. ``times``: (F,) strictly increasing times in s.
    ``ipam_pressures`` / ``ipam_forces``: optional (F, n_ipam) gauge Pa / axial N per frame.
    ``jammed``: optional (F, n_cell) bool jam state per frame. ``targets`` / ``target_names`` /
    ``settings``: stored as in a ``Scene``. ``time_codes_per_second``: the stage's time codes and
    frames per second (default 24). ``duration``: play the sequence over this many seconds (the
    times stretched linearly), default ``times[-1] - times[0]``. ``playback``: how the times were
    made (e.g. ``{"timing": "valve", "simulated_duration_s": 0.29}``), stored in the root layer's
    ``customLayerData`` under ``warpShape:playback`` with the duration. Returns the path.
    """
    path = Path(path)
    check_extension(path)
    if not isinstance(design, Design):
        raise SceneError(f"export_animation needs a ws.Design, got {type(design).__name__}")
    x, t = _checked_frames(design, frames, times)
    nfr = x.shape[0]
    pressures = _per_frame(ipam_pressures, nfr, design.n_ipams, "ipam_pressures", np.float64)
    forces = _per_frame(ipam_forces, nfr, design.n_ipams, "ipam_forces", np.float64)
    jam = _per_frame(jammed, nfr, design.n_cells, "cell_jammed", bool)
    tcps, codes = _time_codes(t, time_codes_per_second, duration)

    scene = Scene(design=design, targets=list(targets or []), target_names=target_names, settings=settings)
    stage = build_stage(scene)
    stage.SetTimeCodesPerSecond(tcps)
    stage.SetFramesPerSecond(tcps)
    stage.SetStartTimeCode(float(codes[0]))
    stage.SetEndTimeCode(float(codes[-1]))
    layer = stage.GetRootLayer()
    data = dict(layer.customLayerData)
    data[f"{NS}:playback"] = {**{k: v for k, v in (playback or {}).items() if v is not None},
                              "duration_s": float(codes[-1] / tcps)}
    layer.customLayerData = data
    tc = [load_pxr().Usd.TimeCode(float(c)) for c in codes]
    _animate_membrane(stage, x, tc)
    for fam in families():  # every actuator family's curves follow the membrane
        if fam.count(design):
            _animate_curves(stage, design, fam, x, tc)
    if design.n_ipams:
        _animate_ipams(stage, x, tc, pressures, forces)
    if jam is not None and design.n_cells:
        _animate_jamming(stage, design, jam, tc)
    return write_stage_atomic(stage, path)


def _checked_frames(design: Design, frames, times) -> tuple[np.ndarray, np.ndarray]:
    """Frames as contiguous float32 (F, V, 3) and times as float64 (F,), checked."""
    nv = design.rest.n_vertices
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
    return x, t


def _per_frame(a, nfr: int, n: int, what: str, dtype):
    """An optional (F, n) per-frame quantity, checked and made contiguous (None stays None)."""
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != (nfr, n):
        raise SceneError(f"{what} must have shape ({nfr}, {n}) (frames, {what.split('_')[0]}s), got {a.shape}")
    if dtype is not bool and not np.all(np.isfinite(a)):
        raise SceneError(f"{what} must be finite")
    return np.ascontiguousarray(a, dtype=dtype)


def _time_codes(t: np.ndarray, time_codes_per_second, duration=None) -> tuple[float, np.ndarray]:
    """Time codes per second and each frame's code, from 0 (times stretched to ``duration`` s)."""
    tcps = float(time_codes_per_second)
    if not (math.isfinite(tcps) and tcps > 0):
        raise SceneError(f"time_codes_per_second must be a positive number, got {time_codes_per_second!r}")
    rel = t - t[0]
    if duration is not None:
        if not (math.isfinite(duration) and duration > 0) or t.size < 2:
            raise SceneError(f"duration must be a positive number of seconds for 2 or more frames, got {duration!r}")
        rel = rel * (float(duration) / rel[-1])
    codes = np.round(rel * tcps, 9)
    if np.any(np.diff(codes) <= 0):
        raise SceneError("frames are closer than 1e-9 time codes apart; raise time_codes_per_second")
    return tcps, codes


def _animate_membrane(stage, x: np.ndarray, tc: list) -> None:
    """Membrane points and extent, one sample per frame."""
    pxr = load_pxr()
    mesh = pxr.UsdGeom.Mesh.Get(stage, f"/{ROOT_NAME}/{MEMBRANE}")
    points, extent = mesh.GetPointsAttr(), mesh.GetExtentAttr()
    ext = np.ascontiguousarray(np.stack([x.min(axis=1), x.max(axis=1)], axis=1))  # (F, 2, 3)
    from_np = pxr.Vt.Vec3fArray.FromNumpy
    for i in range(x.shape[0]):
        points.Set(from_np(x[i]), tc[i])
        extent.Set(from_np(ext[i]), tc[i])


def _animate_curves(stage, design: Design, fam, x: np.ndarray, tc: list) -> None:
    """An actuator family's curve end points (``fam.curve_ends``) and extent per frame."""
    pxr = load_pxr()
    Vt = pxr.Vt
    curves = pxr.UsdGeom.BasisCurves.Get(stage, f"/{ROOT_NAME}/{fam.scene_prim}")
    ends = np.asarray(fam.curve_ends(design, x)).reshape(x.shape[0], -1, 3)
    ends = np.ascontiguousarray(ends, dtype=np.float32)  # (F, 2n, 3)
    eext = np.ascontiguousarray(np.stack([ends.min(axis=1), ends.max(axis=1)], axis=1))
    cpts, cext = curves.GetPointsAttr(), curves.GetExtentAttr()
    for i in range(x.shape[0]):
        cpts.Set(Vt.Vec3fArray.FromNumpy(ends[i]), tc[i])
        cext.Set(Vt.Vec3fArray.FromNumpy(eext[i]), tc[i])


def _animate_ipams(stage, x: np.ndarray, tc: list, pressures, forces) -> None:
    """IPAM pressures and forces per frame when given."""
    pxr = load_pxr()
    Vt = pxr.Vt
    prim = stage.GetPrimAtPath(f"/{ROOT_NAME}/{IPAMS}")
    for name, values in (("pressure", pressures), ("force", forces)):
        if values is None:
            continue
        attr = prim.CreateAttribute(f"{NS}:{name}", pxr.Sdf.ValueTypeNames.DoubleArray, custom=True)
        for i in range(x.shape[0]):
            attr.Set(Vt.DoubleArray.FromNumpy(values[i]), tc[i])


def _animate_jamming(stage, design: Design, jam: np.ndarray, tc: list) -> None:
    """Per-face and per-cell jam state and the cell colours, sampled where the state changes."""
    pxr = load_pxr()
    Sdf, UsdGeom, Vt = pxr.Sdf, pxr.UsdGeom, pxr.Vt
    mesh = UsdGeom.Mesh.Get(stage, f"/{ROOT_NAME}/{MEMBRANE}")
    prim = mesh.GetPrim()
    face_jam = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(f"{NS}:jammed", Sdf.ValueTypeNames.IntArray,
                                                       UsdGeom.Tokens.uniform)
    cell_jam = prim.CreateAttribute(f"{NS}:cellJammed", Sdf.ValueTypeNames.BoolArray, custom=True)
    color = mesh.GetDisplayColorPrimvar()
    face_cell = design.face_cell()
    inside = face_cell >= 0
    prev = None
    for i in range(jam.shape[0]):
        state = jam[i]
        if prev is not None and np.array_equal(state, prev):
            continue
        per_face = np.zeros(design.rest.n_faces, dtype=np.int32)
        per_face[inside] = state[face_cell[inside]].astype(np.int32)
        face_jam.Set(Vt.IntArray.FromNumpy(per_face), tc[i])
        cell_jam.Set(Vt.BoolArray(state.tolist()), tc[i])
        if prev is not None:  # hold the old colour up to the frame before the change (colours interpolate)
            color.Set(Vt.Vec3fArray.FromNumpy(face_colors(design, prev)), tc[i - 1])
        color.Set(Vt.Vec3fArray.FromNumpy(face_colors(design, state)), tc[i])
        prev = state
