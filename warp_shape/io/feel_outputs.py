"""The files of a stiffness map (``warp-shape feel``): per target a figure (the shape coloured by the
stiffness a fingertip feels, N/mm, with a colour bar and the jamming cells outlined), a CSV (one row per
point pressed) and a section of the feel report; each written atomically."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from .atomic import atomic_write

__all__ = ["FEEL_COLUMNS", "feel_rows", "write_feel_csv", "feel_figure", "feel_report_section", "face_stiffness"]

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
    """A Markdown section: the map's spread and where it is softest and stiffest."""
    k = np.asarray(stiffness) / 1000.0
    lo, hi = int(np.argmin(k)), int(np.argmax(k))
    return (f"## Feel: {name}\n\n{len(k)} points pressed {depth * 1e3:.3g} mm by a {radius * 1e3:.3g} mm fingertip "
            f"(the device held at its plug).\n\n| | N/mm |\n|---|---|\n| softest | {k[lo]:.4f} at "
            f"({', '.join(f'{v * 1e3:.1f}' for v in points[lo])}) mm |\n| median | {np.median(k):.4f} |\n"
            f"| stiffest | {k[hi]:.4f} at ({', '.join(f'{v * 1e3:.1f}' for v in points[hi])}) mm |\n")
