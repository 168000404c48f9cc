"""The files of a stiffness map (``warp-shape feel``): per target a figure (the shape coloured by the
stiffness a fingertip feels, N/mm, with a colour bar and the jamming cells outlined), a CSV (one row per
point pressed) and a section of the feel report; each written atomically."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .scene_schema import MEMBRANE, ROOT_NAME
from .scene_write import write_stage_atomic
from .usd_common import load_pxr

__all__ = ["FEEL_COLUMNS", "feel_rows", "write_feel_csv", "feel_figure", "feel_report_section", "face_stiffness",
           "feel_summary", "feel_primvar_name", "add_feel_primvars", "write_feel_maps"]

FEEL_COLUMNS = ["point", "direction_x", "direction_y", "direction_z", "x_m", "y_m", "z_m", "stiffness_n_per_mm"]


def feel_rows(directions: np.ndarray, points: np.ndarray, stiffness: np.ndarray) -> list[dict]:
    """One row per point pressed: its direction, surface point (m) and stiffness (N/mm)."""
    return [dict(zip(FEEL_COLUMNS, [i, *map(float, d), *map(float, p), float(k) / 1000.0]))
            for i, (d, p, k) in enumerate(zip(directions, points, stiffness))]


def write_feel_csv(path, directions, points, stiffness) -> Path:
    """The map as a CSV (``FEEL_COLUMNS``), written atomically."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=FEEL_COLUMNS, lineterminator="\n")
    w.writeheader()
    for row in feel_rows(directions, points, stiffness):
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return atomic_write(path, buf.getvalue())


def face_stiffness(positions: np.ndarray, faces: np.ndarray, points: np.ndarray, stiffness: np.ndarray) -> np.ndarray:
    """(F,) N/m: each face takes the stiffness of the point pressed nearest its direction from the centroid."""
    c = positions.mean(axis=0)
    fc = positions[faces].mean(axis=1) - c
    pc = points - c
    fc /= np.linalg.norm(fc, axis=1, keepdims=True)
    pc /= np.linalg.norm(pc, axis=1, keepdims=True)
    return stiffness[np.argmax(fc @ pc.T, axis=1)]


def feel_figure(path, positions, faces, face_cell, points, stiffness, title: str = "") -> Path:
    """The shape coloured by the stiffness (N/mm) of its nearest pressed point, seen from two sides, with
    a colour bar, the pressed points marked and the cells' borders drawn; a PNG written atomically."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    k = face_stiffness(positions, faces, points, stiffness) / 1000.0
    norm = Normalize(vmin=float(np.min(stiffness)) / 1000.0, vmax=float(np.max(stiffness)) / 1000.0 + 1e-12)
    sm = ScalarMappable(norm=norm, cmap="viridis")
    fig = Figure(figsize=(9, 4.5), dpi=120, layout="constrained")
    border = cell_borders(positions, faces, face_cell)
    for i, (elev, azim) in enumerate(((25, -60), (-20, 120))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(positions[faces], facecolors=sm.to_rgba(k), edgecolors="none"))
        if len(border):
            ax.add_collection3d(Line3DCollection(border, colors="k", linewidths=1.2))
        ax.scatter(*points.T, s=6, c="w", edgecolors="k", linewidths=0.3)
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]), box_aspect=tuple(hi - lo))
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()
    fig.colorbar(sm, ax=fig.axes, shrink=0.7, label="fingertip stiffness, N/mm")
    if title:
        fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return atomic_write(path, buf.getvalue())


def cell_borders(positions: np.ndarray, faces: np.ndarray, face_cell: np.ndarray) -> np.ndarray:
    """(n, 2, 3) the edges between faces of different cells (a cell against no cell included)."""
    owner: dict = {}
    out = []
    for f, tri in enumerate(faces):
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            key = (min(a, b), max(a, b))
            if key in owner and face_cell[owner[key]] != face_cell[f]:
                out.append(positions[list(key)])
            owner[key] = f
    return np.asarray(out, dtype=np.float64).reshape(-1, 2, 3)


def feel_report_section(name: str, stiffness: np.ndarray, depth: float, radius: float, points: np.ndarray) -> str:
    """A Markdown section: the map's spread (N/mm) and where it is softest and stiffest (mm)."""
    k = np.asarray(stiffness) / 1000.0
    lo, hi = int(np.argmin(k)), int(np.argmax(k))
    return (f"## Feel: {name}\n\n{len(k)} points pressed {depth * 1e3:.3g} mm by a {radius * 1e3:.3g} mm fingertip "
            f"(the device held at its plug; stiffness dF/d depth in N/mm, points in mm).\n\n| | N/mm |\n|---|---|\n"
            f"| softest | {k[lo]:.4f} at "
            f"({', '.join(f'{v * 1e3:.1f}' for v in points[lo])}) mm |\n| median | {np.median(k):.4f} |\n"
            f"| stiffest | {k[hi]:.4f} at ({', '.join(f'{v * 1e3:.1f}' for v in points[hi])}) mm |\n"
            + (f"\n{int(np.sum(k <= 0))} point(s) read a stiffness <= 0: there the vertices in contact change "
               "within the stiffness's central difference or the membrane buckles "
               "under the finger; not what a hand feels (docs/feel.md).\n" if np.any(k <= 0) else ""))


def feel_summary(fm) -> dict:
    """A map (``feel.FeelMap``) as JSON-ready data, each key naming its unit."""
    k = np.asarray(fm.stiffness, dtype=np.float64) / 1000.0
    return dict(points=len(k), depth_m=float(fm.depth), radius_m=float(fm.radius),
                min_n_per_mm=float(k.min()), median_n_per_mm=float(np.median(k)), max_n_per_mm=float(k.max()),
                stiffness_n_per_mm=[float(v) for v in k], points_m=np.asarray(fm.points, dtype=np.float64).tolist())


def feel_primvar_name(target: str) -> str:
    """The membrane's primvar holding a target's map: ``feel_stiffness_n_per_mm_<target>`` (characters other
    than letters, digits and _ as _)."""
    return "feel_stiffness_n_per_mm_" + "".join(c if c.isalnum() or c == "_" else "_" for c in target)


def add_feel_primvars(usd_path, faces: np.ndarray, maps: dict) -> Path:
    """Per target of ``maps`` ({name: FeelMap}) a uniform (per face) primvar ``feel_primvar_name(name)`` on the
    membrane of the scene at ``usd_path``: each face's stiffness in N/mm (that of the point pressed nearest its
    direction from the centroid of the controlled shape, as the figure colours it); rewritten atomically."""
    pxr = load_pxr()
    stage = pxr.Usd.Stage.Open(str(usd_path))
    prim = stage.GetPrimAtPath(f"/{ROOT_NAME}/{MEMBRANE}")
    pv = pxr.UsdGeom.PrimvarsAPI(prim)
    for name, fm in maps.items():
        k = face_stiffness(np.asarray(fm.positions), faces, np.asarray(fm.points), np.asarray(fm.stiffness)) / 1000.0
        var = pv.CreatePrimvar(feel_primvar_name(name), pxr.Sdf.ValueTypeNames.FloatArray, pxr.UsdGeom.Tokens.uniform)
        var.Set(pxr.Vt.FloatArray.FromNumpy(k.astype(np.float32)))
        var.GetAttr().SetDocumentation(f"fingertip stiffness in N/mm of the shape controlled to {name}: "
                                       f"{fm.radius * 1e3:.3g} mm fingertip, {fm.depth * 1e3:.3g} mm deep")
    return write_stage_atomic(stage, usd_path)


def write_feel_maps(folder, maps: dict, faces: np.ndarray, face_cell: np.ndarray) -> tuple[list, str]:
    """Per target of ``maps`` ({name: FeelMap}) ``feel_<name>.csv`` and ``feel_<name>.png`` in ``folder``:
    (paths written, the report's Markdown sections)."""
    folder = Path(folder)
    written, sections = [], []
    for name, fm in maps.items():
        written.append(write_feel_csv(folder / f"feel_{name}.csv", fm.directions, fm.points, fm.stiffness))
        try:
            written.append(feel_figure(folder / f"feel_{name}.png", fm.positions, faces, face_cell, fm.points,
                                       fm.stiffness, title=f"{name}: fingertip stiffness at {fm.depth * 1e3:.3g} mm"))
        except ImportError:  # matplotlib missing: the CSV and the report carry the map
            pass
        sections.append(feel_report_section(name, fm.stiffness, fm.depth, fm.radius, fm.points))
    return written, "\n".join(sections)
