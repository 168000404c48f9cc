"""USD helpers shared by the scene writer, the scene reader and the animation export.

``pxr`` (usd-core) is imported only inside these functions (``load_pxr``), so the physics runs
without it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..display import Design
from ..errors import SceneError
from ..interrupts import held_interrupts
from .scene_schema import SCENE_EXTENSIONS

__all__ = ["FRAME_RATE", "load_pxr", "check_extension", "extent", "face_colors", "author_mesh",
           "author_attribute", "MEMBRANE_COLOR", "TARGET_COLOR", "TARGET_OPACITY"]

#: time codes per second and frames per second of every animated stage: the film rate content tools
#: (Blender, usdview, Omniverse) play at, so a second of time codes is a second of playback
FRAME_RATE = 24.0
MEMBRANE_COLOR = (0.86, 0.80, 0.74)  # unjammed silicone
TARGET_COLOR = (0.35, 0.60, 0.90)
TARGET_OPACITY = 0.35
JAMMED_SHADE = 0.45  # a jammed cell's colour is its palette colour times this

#: array value types -> (Vt array class name, numpy dtype) used to author them from numpy
_VT_ARRAYS = {"int[]": ("IntArray", np.int32), "int2[]": ("Vec2iArray", np.int32),
              "double[]": ("DoubleArray", np.float64), "double2[]": ("Vec2dArray", np.float64),
              "point3d[]": ("Vec3dArray", np.float64), "point3f[]": ("Vec3fArray", np.float32),
              "float3[]": ("Vec3fArray", np.float32), "float[]": ("FloatArray", np.float32)}


def load_pxr():
    """The ``pxr`` package (usd-core), or a ``SceneError`` that says how to install it."""
    try:
        with held_interrupts():  # USD swallows a Ctrl-C inside its module loading and is left half loaded
            from pxr import Ar, Kind, Sdf, Tf, Usd, UsdGeom, Vt  # noqa: F401
    except ImportError as exc:  # pragma: no cover - usd-core is an optional dependency
        raise SceneError("reading and writing USD needs usd-core (pip install 'warp-shape[usd]')") from exc
    import pxr

    return pxr


def check_extension(path: Path) -> None:
    """Refuse a path whose suffix is not a USD scene extension."""
    if path.suffix.lower() not in SCENE_EXTENSIONS:
        raise SceneError(f"{path}: a scene file must end in {', '.join(SCENE_EXTENSIONS)}, got {path.suffix!r}")


def _palette(n: int) -> np.ndarray:
    """n distinct, deterministic colours (golden-angle hues), float32 (n, 3)."""
    h = (np.arange(n) * 0.618033988749895 + 0.1) % 1.0
    s, v = 0.65, 0.9
    i = np.floor(h * 6.0).astype(int) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    table = np.stack([np.stack([np.full(n, v), t, np.full(n, p)], 1), np.stack([q, np.full(n, v), np.full(n, p)], 1),
                      np.stack([np.full(n, p), np.full(n, v), t], 1), np.stack([np.full(n, p), q, np.full(n, v)], 1),
                      np.stack([t, np.full(n, p), np.full(n, v)], 1), np.stack([np.full(n, v), np.full(n, p), q], 1)])
    return table[i, np.arange(n)].astype(np.float32)


def face_colors(design: Design, jammed=None) -> np.ndarray:
    """(F, 3) float32 display colours: cells in palette colours (darker once jammed), the rest grey."""
    face_cell = design.face_cell()
    colors = np.tile(np.asarray(MEMBRANE_COLOR, np.float32), (design.rest.n_faces, 1))
    if design.n_cells:
        pal = _palette(design.n_cells)
        if jammed is not None:
            pal = np.where(np.asarray(jammed, bool)[:, None], pal * np.float32(JAMMED_SHADE), pal)
        inside = face_cell >= 0
        colors[inside] = pal[face_cell[inside]]
    return colors


def extent(points: np.ndarray) -> np.ndarray:
    """(2, 3) float32 bounding box (min, max) of (N, 3) points, as USD's ``extent`` holds it."""
    p = np.asarray(points, np.float32)
    return np.stack([p.min(axis=0), p.max(axis=0)])


def author_attribute(prim, name: str, usd_type: str, value):
    """Create the custom attribute ``name`` of Sdf type ``usd_type`` on ``prim`` and set ``value``
    (arrays from numpy, converted to the type's element precision); returns the attribute."""
    pxr = load_pxr()
    if usd_type in _VT_ARRAYS:
        cls, dtype = _VT_ARRAYS[usd_type]
        value = getattr(pxr.Vt, cls).FromNumpy(np.ascontiguousarray(value, dtype=dtype))
    attr = prim.CreateAttribute(name, pxr.Sdf.ValueTypeNames.Find(usd_type), custom=True)
    attr.Set(value)
    return attr


def author_mesh(stage, path: str, vertices: np.ndarray, faces: np.ndarray):
    """Define a triangle ``UsdGeom.Mesh`` at ``path``: counts, indices, float32 points, extent,
    subdivision scheme none (the triangles are the mesh, not a subdivision cage)."""
    pxr = load_pxr()
    Vt, UsdGeom = pxr.Vt, pxr.UsdGeom
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(faces.shape[0], 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, dtype=np.int32).reshape(-1)))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(vertices, dtype=np.float32)))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent(vertices)))
    return mesh
