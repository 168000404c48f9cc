"""Write a ``Scene`` as a USD stage and save it to a ``.usda`` / ``.usdc`` / ``.usd`` file, atomically.

The format is ``docs/scene_format.md``; the attribute names and types come from the table in
``scene_schema``. Files are written through a temporary file in the same directory and a rename.
"""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path

import numpy as np

from ..force_family import families
from ..display import Design
from ..errors import SceneError
from .atomic import atomic_target
from .scene_schema import (CELL_FAMILY, FORMAT_VERSION_ATTRIBUTE, MATERIAL_ATTRIBUTES, MEMBRANE, NS, REST_POINTS,
                           ROOT_NAME, SCENE_FORMAT_VERSION, SETTINGS, TARGET_POINTS, TARGETS, Scene)
from .usd_common import (TARGET_COLOR, TARGET_OPACITY, author_attribute, author_mesh, check_extension, extent,
                         face_colors, load_pxr)

__all__ = ["build_stage", "save_scene", "write_stage_atomic", "export_layer", "usd_write_error"]

#: Python type of a setting -> its USD type (bool before int: a bool is an int in Python)
SETTING_TYPES = ((bool, "bool"), (int, "int64"), (float, "double"), (str, "string"))


def build_stage(scene: Scene, stage=None, *, target_references: dict | None = None, asset_dir=None):
    """Author ``scene`` into ``stage`` (a new in-memory stage by default) and return the stage.

    ``target_references`` maps a target name to the asset path of a scene file holding
    ``/Scene/Targets/<name>``; such a target is written as a USD reference instead of inline.
    ``asset_dir``: directory that relative references resolve against while the stage is in memory
    (the directory the file will be written to).
    """
    pxr = load_pxr()
    if not isinstance(scene, Scene):
        raise SceneError(f"expected a ws.Scene, got {type(scene).__name__}")
    if stage is None:
        if asset_dir is not None:
            ctx = pxr.Ar.DefaultResolverContext([str(Path(asset_dir).resolve())])
            stage = pxr.Usd.Stage.CreateInMemory("scene.usda", ctx)
        else:
            stage = pxr.Usd.Stage.CreateInMemory()
    _author_root(stage)
    if scene.design is not None:
        _author_membrane(stage, scene.design)
        for fam in families():
            if fam.count(scene.design):
                _author_family(stage, scene.design, fam)
    if scene.targets:
        _author_targets(stage, scene, dict(target_references or {}))
    if scene.settings:
        _author_settings(stage, scene.settings)
    return stage


def _author_root(stage) -> None:
    """Stage metadata (Z up, metres) and the default prim with the format version."""
    pxr = load_pxr()
    UsdGeom = pxr.UsdGeom
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, f"/{ROOT_NAME}").GetPrim()
    stage.SetDefaultPrim(root)
    pxr.Usd.ModelAPI(root).SetKind(pxr.Kind.Tokens.component)
    author_attribute(root, FORMAT_VERSION_ATTRIBUTE, "int", SCENE_FORMAT_VERSION)
    stage.GetRootLayer().documentation = "warp_shape scene (format: docs/scene_format.md)"


def _author_membrane(stage, d: Design) -> None:
    """The rest membrane: mesh, exact rest points, material, cell ids and colours, one subset per cell."""
    pxr = load_pxr()
    Sdf, UsdGeom, Vt = pxr.Sdf, pxr.UsdGeom, pxr.Vt
    path = f"/{ROOT_NAME}/{MEMBRANE}"
    mesh = author_mesh(stage, path, d.rest.vertices, d.rest.faces)
    prim = mesh.GetPrim()
    author_attribute(prim, REST_POINTS, "point3d[]", d.rest.vertices)
    for attr in MATERIAL_ATTRIBUTES:
        value = getattr(d.material, attr.field)
        if value is not None and (attr.field, value) != ("compression", "solid"):  # shear_modulus None (E / 3)
            # and the default compression are written as no attribute (scenes written before them read the same)
            author_attribute(prim, attr.name, attr.usd_type, value if attr.usd_type == "token" else float(value))
    pv = UsdGeom.PrimvarsAPI(prim)
    pv.CreatePrimvar(f"{NS}:cellId", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform).Set(
        Vt.IntArray.FromNumpy(d.face_cell().astype(np.int32)))
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(face_colors(d)))
    for c, cell in enumerate(d.cells):
        sub = UsdGeom.Subset.Define(stage, f"{path}/Cell_{c:03d}")
        sub.CreateElementTypeAttr(UsdGeom.Tokens.face)
        sub.CreateFamilyNameAttr(CELL_FAMILY)
        sub.CreateIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(cell.faces, dtype=np.int32)))
    if d.n_cells:
        UsdGeom.Subset.SetFamilyType(mesh, CELL_FAMILY, UsdGeom.Tokens.nonOverlapping)


def _author_family(stage, d: Design, fam) -> None:
    """Every element of an actuator family as a 2-point linear curve (``fam.curve_ends``) on the
    family's prim, with its attributes (``fam.scene_attributes``, one array element per element)."""
    pxr = load_pxr()
    UsdGeom, Vt = pxr.UsdGeom, pxr.Vt
    n = fam.count(d)
    curves = UsdGeom.BasisCurves.Define(stage, f"/{ROOT_NAME}/{fam.scene_prim}")
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(n, 2, dtype=np.int32)))
    ends = np.asarray(fam.curve_ends(d, d.rest.vertices)).reshape(2 * n, 3)
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(ends, dtype=np.float32)))
    curves.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent(ends)))
    curves.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.asarray(fam.curve_widths(d), dtype=np.float32)))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.uniform)
    curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([tuple(fam.color)]))
    prim = curves.GetPrim()
    for attr in fam.scene_attributes:
        author_attribute(prim, attr.name, attr.usd_type, fam.attribute_values(d, attr))


def _author_targets(stage, scene: Scene, refs: dict) -> None:
    """The targets (guides): inline meshes with exact points, or references to other scene files."""
    pxr = load_pxr()
    Sdf, UsdGeom, Vt = pxr.Sdf, pxr.UsdGeom, pxr.Vt
    unknown = sorted(set(refs) - set(scene.target_names))
    if unknown:
        raise SceneError(f"target_references names unknown target(s) {unknown}; targets are {scene.target_names}")
    scope = UsdGeom.Scope.Define(stage, f"/{ROOT_NAME}/{TARGETS}")
    scope.CreatePurposeAttr(UsdGeom.Tokens.guide)
    for name, tgt in zip(scene.target_names, scene.targets):
        path = f"/{ROOT_NAME}/{TARGETS}/{name}"
        if name in refs:
            prim = stage.DefinePrim(path, "Mesh")
            prim.GetReferences().AddReference(str(refs[name]), Sdf.Path(path))
            continue
        mesh = author_mesh(stage, path, tgt.vertices, tgt.faces)
        mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
        author_attribute(mesh.GetPrim(), TARGET_POINTS, "point3d[]", tgt.vertices)
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([TARGET_COLOR]))
        mesh.CreateDisplayOpacityPrimvar(UsdGeom.Tokens.constant).Set(Vt.FloatArray([TARGET_OPACITY]))


def _author_settings(stage, settings: dict) -> None:
    """Settings as ``warpShape:<group>:<key>`` attributes of a Settings scope."""
    prim = load_pxr().UsdGeom.Scope.Define(stage, f"/{ROOT_NAME}/{SETTINGS}").GetPrim()
    for group, entries in settings.items():
        for key, value in entries.items():
            usd_type = next(t for py, t in SETTING_TYPES if isinstance(value, py))
            author_attribute(prim, f"{NS}:{group}:{key}", usd_type, value)


def export_layer(layer, path: str) -> None:
    """Write ``layer`` to ``path`` (format by extension). Separate so that tests can inject a failure."""
    if not layer.Export(path):
        raise SceneError(f"USD could not write {path}")


def write_stage_atomic(stage, path) -> Path:
    """Export a stage's root layer to ``path`` through a temporary file and a rename.

    A failure leaves neither a partial ``path`` nor the temporary file.
    """
    path = Path(path)
    check_extension(path)
    with atomic_target(path) as tmp:
        try:
            export_layer(stage.GetRootLayer(), str(tmp))
        except load_pxr().Tf.ErrorException as exc:
            raise usd_write_error(exc, path) from None
    return path


def usd_write_error(exc, path) -> Exception:
    """USD's refusal to write ``path`` (a ``Tf.ErrorException`` of many lines) as one error: the
    ``OSError`` of a full or failing disk, else a ``SceneError`` with USD's first reason."""
    text = str(exc)
    for code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO):
        if os.strerror(code) in text:
            return OSError(code, os.strerror(code), str(path))
    reasons = re.findall(r" : '(.*)'\s*$", text, re.M)
    first = reasons[0] if reasons else (text.strip().splitlines() or [type(exc).__name__])[0]
    return SceneError(f"USD could not write {path}: {first}")


def save_scene(scene: Scene, path, *, target_references: dict | None = None) -> Path:
    """Write ``scene`` to ``path`` (``.usda`` text, ``.usdc`` / ``.usd`` binary), atomically.

    ``target_references``: see ``build_stage`` (used by ``scripts/make_scenes.py`` so that the
    shipped problems share the shipped target files).
    """
    path = Path(path)
    check_extension(path)
    stage = build_stage(scene, target_references=target_references,
                        asset_dir=path.parent if target_references else None)
    return write_stage_atomic(stage, path)
