"""Scenes as USD: a design, its targets and its settings in one ``.usda`` / ``.usdc`` / ``.usd`` file.

The format is documented in ``docs/scene_format.md``. In short, under the default prim ``/Scene``
(Z up, metersPerUnit 1):

- ``Membrane`` (UsdGeom.Mesh): the rest membrane (``points`` float32 for viewers and
  ``warpShape:restPoints`` point3d[] exact), every ``Material`` field as a ``double
  warpShape:<camelCaseName>`` attribute (SI), one ``GeomSubset`` per jamming cell (family
  ``jammingCell``), per-face ``primvars:warpShape:cellId`` and ``primvars:displayColor``;
- ``Ipams`` (UsdGeom.BasisCurves, linear, one 2-point curve per IPAM): end-face centroids as
  points, ``warpShape:faces`` int2[] and per-IPAM ``warpShape:stiffness``, ``area``, ``freeLength``,
  ``pressureLimits``, ``damping``;
- ``Targets`` (Scope, purpose guide): one UsdGeom.Mesh per target (``warpShape:points`` exact);
- ``Settings`` (Scope): ``warpShape:<group>:<key>`` attributes (bool, int, double or string).

``pxr`` (usd-core) is imported only inside the functions that need it, so the physics runs without
it. Files are written atomically (temporary file in the same directory, then a rename).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..design import Design
from ..errors import DesignError, MeshError, SceneError
from ..material import Material
from ..mesh import TriMesh
from .atomic import atomic_target

__all__ = ["Scene", "save_scene", "load_scene", "list_scenes", "scene_dirs", "validate_usd", "build_stage",
           "read_stage", "write_stage_atomic", "face_colors", "ipam_endpoints", "MATERIAL_ATTRIBUTES",
           "SCENE_FORMAT_VERSION", "SCENE_EXTENSIONS", "DEFAULT_SIMULATION_SETTINGS"]

SCENE_FORMAT_VERSION = 1
SCENE_EXTENSIONS = (".usda", ".usdc", ".usd")
NS = "warpShape"
ROOT_NAME = "Scene"
CELL_FAMILY = "jammingCell"
DEFAULT_SIMULATION_SETTINGS = {"integrator": "rk4", "dt": 1e-3, "precision": "float32", "bending": "exact"}

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
MEMBRANE_COLOR = (0.86, 0.80, 0.74)  # unjammed silicone
TARGET_COLOR = (0.35, 0.60, 0.90)
IPAM_COLOR = (0.08, 0.08, 0.08)


def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(w[:1].upper() + w[1:] for w in rest)


#: Material field -> attribute name on the Membrane prim.
MATERIAL_ATTRIBUTES = {f.name: f"{NS}:{_camel(f.name)}" for f in fields(Material)}


# ---------------------------------------------------------------------------------------------- Scene
@dataclass(eq=False)
class Scene:
    """A design problem or a design: membrane + IPAMs + cells (``design``), targets and settings.

    ``design``: a ``ws.Design`` or None (a scene that only holds targets).
    ``targets``: list of ``TriMesh`` (or target names such as ``"oval"``, resolved by
    ``ws.target``). ``target_names``: one identifier per target (default: the names given as
    strings, else ``target0``, ``target1``, ...); they become the prim names under ``Targets``.
    ``settings``: ``{group: {key: value}}`` with identifier groups and keys and bool / int / float /
    str values, e.g. ``{"simulation": {"dt": 1e-3}, "designer": {"actuators": 4}}``.
    """

    design: Design | None = None
    targets: list = field(default_factory=list)
    settings: dict | None = None
    target_names: list | None = None

    def __post_init__(self):
        if self.design is not None and not isinstance(self.design, Design):
            raise SceneError(f"Scene.design must be a ws.Design or None, got {type(self.design).__name__}")
        if isinstance(self.targets, TriMesh):
            self.targets = [self.targets]
        raw = list(self.targets or [])
        names_given = None if self.target_names is None else [str(n) for n in self.target_names]
        meshes, auto_names = [], []
        for i, t in enumerate(raw):
            if isinstance(t, str):
                from ..targets import target

                meshes.append(target(t))
                auto_names.append(t.strip().lower())
            elif isinstance(t, TriMesh):
                meshes.append(t)
                auto_names.append(f"target{i}")
            else:
                raise SceneError(f"Scene.targets[{i}] must be a TriMesh or a target name, got {type(t).__name__}")
        if names_given is None:
            names_given = auto_names
        if len(names_given) != len(meshes):
            raise SceneError(f"Scene.target_names has {len(names_given)} names for {len(meshes)} targets")
        for n in names_given:
            if not _IDENT.match(n):
                raise SceneError(f"target name {n!r} is not an identifier (letters, digits, _; not starting "
                                 f"with a digit); it becomes a USD prim name")
        if len(set(names_given)) != len(names_given):
            raise SceneError(f"target names must be unique, got {names_given}")
        self.targets = meshes
        self.target_names = names_given
        self.settings = _check_settings(self.settings)

    # ------------------------------------------------------------------ conveniences
    def target(self, name: str) -> TriMesh:
        """The target called ``name``."""
        try:
            return self.targets[self.target_names.index(name)]
        except ValueError:
            raise SceneError(f"scene has no target {name!r}; it has {self.target_names}") from None

    @property
    def simulation_settings(self) -> dict:
        """``DEFAULT_SIMULATION_SETTINGS`` updated by the scene's ``settings["simulation"]``."""
        out = dict(DEFAULT_SIMULATION_SETTINGS)
        out.update(self.settings.get("simulation", {}))
        return out

    def simulator(self, device: str = "cpu", **overrides):
        """A ``ws.Simulator`` of the scene's design with its simulation settings (overridable)."""
        if self.design is None:
            raise SceneError("this scene holds no design (targets only); nothing to simulate")
        from ..simulator import Simulator

        kw = self.simulation_settings
        kw.update(overrides)
        return Simulator(self.design, device=device, **kw)

    def __repr__(self) -> str:
        return (f"Scene(design={self.design!r}, targets={self.target_names}, "
                f"settings={sorted(self.settings)})")


def _check_settings(settings) -> dict:
    if settings is None:
        return {}
    if not isinstance(settings, dict):
        raise SceneError(f"Scene.settings must be a dict {{group: {{key: value}}}}, got {type(settings).__name__}")
    out = {}
    for group, entries in settings.items():
        if not isinstance(group, str) or not _IDENT.match(group):
            raise SceneError(f"settings group {group!r} must be an identifier (it becomes part of an attribute name)")
        if not isinstance(entries, dict):
            raise SceneError(f"settings[{group!r}] must be a dict of key -> bool/int/float/str, "
                             f"got {type(entries).__name__}")
        g = {}
        for key, value in entries.items():
            if not isinstance(key, str) or not _IDENT.match(key):
                raise SceneError(f"settings[{group!r}] key {key!r} must be an identifier")
            if isinstance(value, (bool, np.bool_)):
                value = bool(value)
            elif isinstance(value, (int, np.integer)):
                value = int(value)
                if not -(2**63) <= value < 2**63:
                    raise SceneError(f"settings[{group!r}][{key!r}] = {value} does not fit in 64 bits")
            elif isinstance(value, (float, np.floating)):
                value = float(value)
            elif isinstance(value, str):
                pass
            else:
                raise SceneError(f"settings[{group!r}][{key!r}] must be a bool, int, float or str, "
                                 f"got {type(value).__name__}")
            g[key] = value
        out[group] = g
    return out


# ---------------------------------------------------------------------------------------------- utilities
def _pxr():
    try:
        from pxr import Ar, Kind, Sdf, Tf, Usd, UsdGeom, Vt  # noqa: F401
    except ImportError as exc:  # pragma: no cover - usd-core is an optional dependency
        raise SceneError("reading and writing USD needs usd-core (pip install 'warp-shape[usd]')") from exc
    import pxr

    return pxr


def _check_extension(path: Path) -> None:
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
            pal = np.where(np.asarray(jammed, bool)[:, None], pal * np.float32(0.45), pal)
        inside = face_cell >= 0
        colors[inside] = pal[face_cell[inside]]
    return colors


def _extent(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, np.float32)
    return np.stack([p.min(axis=0), p.max(axis=0)])


def _ipam_end_faces(design: Design) -> np.ndarray:
    """(2 n_ipam,) face index of each curve point: a0, b0, a1, b1, ..."""
    return np.array([[ip.face_a, ip.face_b] for ip in design.ipams], dtype=np.int64).reshape(-1)


def ipam_endpoints(design: Design, positions) -> np.ndarray:
    """End-face centroids of every IPAM, (2 n_ipam, 3) (or (..., 2 n_ipam, 3) for stacked frames)."""
    x = np.asarray(positions)
    tri = design.rest.faces[_ipam_end_faces(design)]  # (2n, 3)
    return x[..., tri, :].mean(axis=-2)


def _new_attr(prim, name, type_name, value, Sdf):
    attr = prim.CreateAttribute(name, type_name, custom=True)
    attr.Set(value)
    return attr


# ---------------------------------------------------------------------------------------------- writing
def _author_mesh(stage, path: str, vertices: np.ndarray, faces: np.ndarray, pxr):
    Vt, UsdGeom = pxr.Vt, pxr.UsdGeom
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(faces.shape[0], 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, dtype=np.int32).reshape(-1)))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(vertices, dtype=np.float32)))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(_extent(vertices)))
    return mesh


def build_stage(scene: Scene, stage=None, *, target_references: dict | None = None, asset_dir=None):
    """Author ``scene`` into ``stage`` (a new in-memory stage by default) and return the stage.

    ``target_references`` maps a target name to the asset path of a scene file holding
    ``/Scene/Targets/<name>``; such a target is written as a USD reference instead of inline.
    ``asset_dir``: directory that relative references resolve against while the stage is in memory
    (the directory the file will be written to).
    """
    pxr = _pxr()
    Sdf, Usd, UsdGeom, Vt = pxr.Sdf, pxr.Usd, pxr.UsdGeom, pxr.Vt
    if not isinstance(scene, Scene):
        raise SceneError(f"expected a ws.Scene, got {type(scene).__name__}")
    if stage is None:
        if asset_dir is not None:
            ctx = pxr.Ar.DefaultResolverContext([str(Path(asset_dir).resolve())])
            stage = Usd.Stage.CreateInMemory("scene.usda", ctx)
        else:
            stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, f"/{ROOT_NAME}").GetPrim()
    stage.SetDefaultPrim(root)
    pxr.Usd.ModelAPI(root).SetKind(pxr.Kind.Tokens.component)
    _new_attr(root, f"{NS}:formatVersion", Sdf.ValueTypeNames.Int, SCENE_FORMAT_VERSION, Sdf)
    stage.GetRootLayer().documentation = "warp_shape scene (format: docs/scene_format.md)"

    d = scene.design
    if d is not None:
        rest = d.rest
        mesh = _author_mesh(stage, f"/{ROOT_NAME}/Membrane", rest.vertices, rest.faces, pxr)
        prim = mesh.GetPrim()
        _new_attr(prim, f"{NS}:restPoints", Sdf.ValueTypeNames.Point3dArray,
                  Vt.Vec3dArray.FromNumpy(np.ascontiguousarray(rest.vertices, dtype=np.float64)), Sdf)
        for name, attr_name in MATERIAL_ATTRIBUTES.items():
            _new_attr(prim, attr_name, Sdf.ValueTypeNames.Double, float(getattr(d.material, name)), Sdf)
        pv = UsdGeom.PrimvarsAPI(prim)
        pv.CreatePrimvar(f"{NS}:cellId", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform).Set(
            Vt.IntArray.FromNumpy(d.face_cell().astype(np.int32)))
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(face_colors(d)))
        for c, cell in enumerate(d.cells):
            sub = UsdGeom.Subset.Define(stage, f"/{ROOT_NAME}/Membrane/Cell_{c:03d}")
            sub.CreateElementTypeAttr(UsdGeom.Tokens.face)
            sub.CreateFamilyNameAttr(CELL_FAMILY)
            sub.CreateIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(cell.faces, dtype=np.int32)))
        if d.n_cells:
            UsdGeom.Subset.SetFamilyType(mesh, CELL_FAMILY, UsdGeom.Tokens.nonOverlapping)

        if d.n_ipams:
            n = d.n_ipams
            curves = UsdGeom.BasisCurves.Define(stage, f"/{ROOT_NAME}/Ipams")
            curves.CreateTypeAttr(UsdGeom.Tokens.linear)
            curves.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(n, 2, dtype=np.int32)))
            ends = ipam_endpoints(d, rest.vertices)
            curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(ends, dtype=np.float32)))
            curves.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(_extent(ends)))
            widths = np.array([2.0 * math.sqrt(ip.area / math.pi) for ip in d.ipams], dtype=np.float32)
            curves.CreateWidthsAttr(Vt.FloatArray.FromNumpy(widths))
            curves.SetWidthsInterpolation(UsdGeom.Tokens.uniform)
            curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([IPAM_COLOR]))
            cp = curves.GetPrim()
            T = Sdf.ValueTypeNames

            def arr(values, dtype=np.float64):
                return np.ascontiguousarray(np.asarray(values, dtype=dtype))

            _new_attr(cp, f"{NS}:faces", T.Int2Array,
                      Vt.Vec2iArray.FromNumpy(arr([[ip.face_a, ip.face_b] for ip in d.ipams], np.int32)), Sdf)
            _new_attr(cp, f"{NS}:stiffness", T.DoubleArray, Vt.DoubleArray.FromNumpy(arr([ip.stiffness for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:area", T.DoubleArray, Vt.DoubleArray.FromNumpy(arr([ip.area for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:areaOverStiffness", T.DoubleArray,
                      Vt.DoubleArray.FromNumpy(arr([ip.area_over_stiffness for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:freeLength", T.DoubleArray, Vt.DoubleArray.FromNumpy(arr([ip.free_length for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:restLength", T.DoubleArray, Vt.DoubleArray.FromNumpy(arr([ip.rest_length for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:pressureLimits", T.Double2Array,
                      Vt.Vec2dArray.FromNumpy(arr([ip.pressure_limits for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:damping", T.DoubleArray, Vt.DoubleArray.FromNumpy(arr([ip.damping for ip in d.ipams])), Sdf)
            _new_attr(cp, f"{NS}:pairs", T.Int2Array,
                      Vt.Vec2iArray.FromNumpy(arr(np.concatenate([ip.pairs for ip in d.ipams]), np.int32)), Sdf)
            _new_attr(cp, f"{NS}:offsets", T.DoubleArray,
                      Vt.DoubleArray.FromNumpy(arr(np.concatenate([ip.offsets for ip in d.ipams]))), Sdf)

    if scene.targets:
        scope = UsdGeom.Scope.Define(stage, f"/{ROOT_NAME}/Targets")
        scope.CreatePurposeAttr(UsdGeom.Tokens.guide)
        refs = dict(target_references or {})
        unknown = sorted(set(refs) - set(scene.target_names))
        if unknown:
            raise SceneError(f"target_references names unknown target(s) {unknown}; targets are {scene.target_names}")
        for name, tgt in zip(scene.target_names, scene.targets):
            path = f"/{ROOT_NAME}/Targets/{name}"
            if name in refs:
                prim = stage.DefinePrim(path, "Mesh")
                prim.GetReferences().AddReference(str(refs[name]), Sdf.Path(path))
                continue
            mesh = _author_mesh(stage, path, tgt.vertices, tgt.faces, pxr)
            mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
            _new_attr(mesh.GetPrim(), f"{NS}:points", Sdf.ValueTypeNames.Point3dArray,
                      Vt.Vec3dArray.FromNumpy(np.ascontiguousarray(tgt.vertices, dtype=np.float64)), Sdf)
            mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([TARGET_COLOR]))
            mesh.CreateDisplayOpacityPrimvar(UsdGeom.Tokens.constant).Set(Vt.FloatArray([0.35]))

    if scene.settings:
        sprim = UsdGeom.Scope.Define(stage, f"/{ROOT_NAME}/Settings").GetPrim()
        T = Sdf.ValueTypeNames
        for group, entries in scene.settings.items():
            for key, value in entries.items():
                name = f"{NS}:{group}:{key}"
                if isinstance(value, bool):
                    _new_attr(sprim, name, T.Bool, value, Sdf)
                elif isinstance(value, int):
                    _new_attr(sprim, name, T.Int64, value, Sdf)
                elif isinstance(value, float):
                    _new_attr(sprim, name, T.Double, value, Sdf)
                else:
                    _new_attr(sprim, name, T.String, value, Sdf)
    return stage


def _export_layer(layer, path: str) -> None:
    """Write ``layer`` to ``path`` (format by extension). Separate so that tests can inject a failure."""
    if not layer.Export(path):
        raise SceneError(f"USD could not write {path}")


def write_stage_atomic(stage, path) -> Path:
    """Export a stage's root layer to ``path`` through a temporary file and a rename.

    A failure leaves neither a partial ``path`` nor the temporary file.
    """
    path = Path(path)
    _check_extension(path)
    with atomic_target(path) as tmp:
        _export_layer(stage.GetRootLayer(), str(tmp))
    return path


def save_scene(scene: Scene, path, *, target_references: dict | None = None) -> Path:
    """Write ``scene`` to ``path`` (``.usda`` text, ``.usdc`` / ``.usd`` binary), atomically.

    ``target_references``: see ``build_stage`` (used by ``scripts/make_scenes.py`` so that the
    shipped problems share the shipped target files).
    """
    path = Path(path)
    _check_extension(path)
    stage = build_stage(scene, target_references=target_references, asset_dir=path.parent if target_references else None)
    return write_stage_atomic(stage, path)


# ---------------------------------------------------------------------------------------------- reading
class _Reader:
    """Reads typed attributes and raises ``SceneError`` naming the file, prim path and attribute."""

    def __init__(self, source: str):
        self.source = source

    def error(self, prim, attr: str | None, message: str) -> SceneError:
        p = str(prim.GetPath()) if hasattr(prim, "GetPath") else str(prim)
        where = f"<{p}>" + (f".{attr}" if attr else "")
        return SceneError(f"{self.source}: {where}: {message}", prim=p, attribute=attr)

    def attr(self, prim, name: str, required: bool = True):
        a = prim.GetAttribute(name)
        if not a or not a.HasAuthoredValue():
            if required:
                raise self.error(prim, name, "required attribute is missing (see docs/scene_format.md)")
            return None
        return a

    def _typed(self, prim, name, required, accept, what):
        a = self.attr(prim, name, required)
        if a is None:
            return None, None
        tn = a.GetTypeName()
        if not accept(tn):
            raise self.error(prim, name, f"has type {tn}, expected {what}")
        value = a.Get()
        if value is None:
            raise self.error(prim, name, "has no value")
        return a, value

    def scalar(self, prim, name, required=True):
        numeric = {"double", "float", "half", "int", "int64", "uint", "uint64", "uchar"}
        _, v = self._typed(prim, name, required, lambda t: not t.isArray and str(t) in numeric, "a number (double)")
        if v is None:
            return None
        v = float(v)
        if not math.isfinite(v):
            raise self.error(prim, name, f"must be finite, got {v}")
        return v

    def int_array(self, prim, name, required=True, width=1):
        kinds = {1: {"int", "int64", "uint", "uint64"}, 2: {"int2"}}[width]
        what = "int[]" if width == 1 else "int2[]"
        _, v = self._typed(prim, name, required, lambda t: t.isArray and str(t.scalarType) in kinds, what)
        if v is None:
            return None
        a = np.array(v, dtype=np.int64)
        return a.reshape(-1) if width == 1 else a.reshape(-1, width)

    def float_array(self, prim, name, required=True, width=1):
        kinds = {1: {"double", "float", "half"}, 2: {"double2", "float2", "half2"},
                 3: {"double3", "float3", "half3", "point3d", "point3f", "point3h", "vector3d", "vector3f",
                     "normal3d", "normal3f"}}[width]
        what = {1: "double[]", 2: "double2[]", 3: "point3d[] or point3f[]"}[width]
        _, v = self._typed(prim, name, required, lambda t: t.isArray and str(t.scalarType) in kinds, what)
        if v is None:
            return None
        a = np.array(v, dtype=np.float64)
        a = a.reshape(-1) if width == 1 else a.reshape(-1, width)
        if not np.all(np.isfinite(a)):
            i = int(np.flatnonzero(~np.isfinite(a.reshape(a.shape[0], -1)).any(axis=1))[0])
            raise self.error(prim, name, f"element {i} is not finite: {a[i]}")
        return a

    def token(self, prim, name, required=True):
        _, v = self._typed(prim, name, required, lambda t: not t.isArray and str(t) in ("token", "string"),
                           "a token")
        return None if v is None else str(v)

    def triangles(self, prim, points_attr: str, fallback: str | None = None):
        """Vertices (float64) and triangle faces of a Mesh prim."""
        counts = self.int_array(prim, "faceVertexCounts")
        idx = self.int_array(prim, "faceVertexIndices")
        if counts.size == 0 or np.any(counts != 3):
            bad = int(np.flatnonzero(counts != 3)[0]) if counts.size else 0
            raise self.error(prim, "faceVertexCounts", f"every face must be a triangle (count 3); face {bad} has "
                             f"{int(counts[bad]) if counts.size else 'none'}; triangulate the mesh first")
        if idx.size != 3 * counts.size:
            raise self.error(prim, "faceVertexIndices", f"has {idx.size} indices, expected {3 * counts.size} "
                             f"(3 per face of faceVertexCounts)")
        verts = self.float_array(prim, points_attr, required=fallback is None, width=3)
        used = points_attr
        if verts is None:
            verts = self.float_array(prim, fallback, width=3)
            used = fallback
        if idx.min() < 0 or idx.max() >= verts.shape[0]:
            bad = int(np.flatnonzero((idx < 0) | (idx >= verts.shape[0]))[0])
            raise self.error(prim, "faceVertexIndices", f"index {int(idx[bad])} (face {bad // 3}) is out of range: "
                             f"{used} has {verts.shape[0]} points")
        faces = idx.reshape(-1, 3)
        try:
            mesh = TriMesh(verts, faces)
        except MeshError as exc:
            raise self.error(prim, f"faceVertexIndices/{used}", f"not a valid closed membrane mesh: {exc}") from None
        return mesh, used


def _resolve(path_or_name) -> Path:
    if isinstance(path_or_name, Path) or any(s in str(path_or_name) for s in ("/", "\\")) or \
            str(path_or_name).lower().endswith(SCENE_EXTENSIONS):
        p = Path(path_or_name)
        if not p.exists():
            raise SceneError(f"scene file not found: {p}")
        return p
    name = str(path_or_name)
    for d in scene_dirs():
        for ext in SCENE_EXTENSIONS:
            cand = d / f"{name}{ext}"
            if cand.exists():
                return cand
    p = Path(name)
    if p.exists():
        return p
    raise SceneError(f"unknown scene {name!r}; shipped scenes: {', '.join(list_scenes()) or '(none found)'}")


def scene_dirs() -> list[Path]:
    """Directories searched for scenes by name: the repository's ``scenes/`` and ``warp_shape/scenes``."""
    package = Path(__file__).resolve().parents[1]
    return [d for d in (package.parent / "scenes", package / "scenes") if d.is_dir()]


def list_scenes() -> list[str]:
    """Names of the shipped scenes (loadable with ``load_scene(name)``)."""
    names = set()
    for d in scene_dirs():
        for p in d.iterdir():
            if p.suffix.lower() in SCENE_EXTENSIONS and not p.name.startswith("."):
                names.add(p.stem)
    return sorted(names)


def _open_stage(path: Path):
    pxr = _pxr()
    Sdf, Usd, Tf = pxr.Sdf, pxr.Usd, pxr.Tf
    # a layer still open elsewhere under this identifier would be served stale: reload it
    existing = Sdf.Layer.Find(str(path))
    if existing:
        existing.Reload(force=True)
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as exc:
        msg = " ".join(str(exc).split())
        raise SceneError(f"{path}: not a readable USD file (truncated or corrupt?): {msg}") from None
    if stage is None:
        raise SceneError(f"{path}: USD could not open the file")
    errors = stage.GetCompositionErrors() if hasattr(stage, "GetCompositionErrors") else []
    if errors:
        first = " ".join(str(errors[0]).split())
        raise SceneError(f"{path}: {len(errors)} composition error(s), first: {first} (a referenced file is "
                         f"missing? shipped problem scenes reference the target_<name>.usda files next to them)")
    return stage


def read_stage(stage, source: str = "<stage>") -> Scene:
    """Read a warp_shape scene from an open USD stage (see ``load_scene``)."""
    pxr = _pxr()
    UsdGeom = pxr.UsdGeom
    r = _Reader(source)
    root = stage.GetDefaultPrim()
    if not root:
        raise SceneError(f"{source}: the stage has no defaultPrim; a warp_shape scene sets defaultPrim = "
                         f"\"{ROOT_NAME}\"", attribute="defaultPrim")
    version = r.scalar(root, f"{NS}:formatVersion")
    if version != SCENE_FORMAT_VERSION:
        raise r.error(root, f"{NS}:formatVersion", f"format version {version:g} is not supported "
                      f"(this build reads version {SCENE_FORMAT_VERSION})")
    up = UsdGeom.GetStageUpAxis(stage)
    if up != UsdGeom.Tokens.z:
        raise SceneError(f"{source}: upAxis is {up!r}; warp_shape scenes are Z-up", attribute="upAxis")
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    if mpu != 1.0:
        raise SceneError(f"{source}: metersPerUnit is {mpu}; warp_shape scenes are in metres (metersPerUnit = 1)",
                         attribute="metersPerUnit")

    design = None
    membrane = root.GetChild("Membrane")
    if membrane:
        if not membrane.IsA(UsdGeom.Mesh):
            raise r.error(membrane, None, f"must be a Mesh, is a {membrane.GetTypeName() or 'typeless prim'}")
        rest, used = r.triangles(membrane, f"{NS}:restPoints", fallback="points")
        if used != "points":  # the viewer points must agree with the exact rest points
            shown = r.float_array(membrane, "points", required=False, width=3)
            if shown is not None:
                tol = 1e-6 * float(np.abs(rest.vertices).max()) + 1e-9
                if shown.shape != rest.vertices.shape or np.abs(shown - rest.vertices).max() > tol:
                    raise r.error(membrane, "points", f"disagrees with {NS}:restPoints (edited in another tool?); "
                                  f"remove {NS}:restPoints to use the edited points")
        values = {}
        for fname, aname in MATERIAL_ATTRIBUTES.items():
            values[fname] = r.scalar(membrane, aname)
        try:
            material = Material.from_dict(values)
        except DesignError as exc:
            msg = str(exc)
            bad = next((a for f, a in MATERIAL_ATTRIBUTES.items() if f"Material.{f} " in msg), None)
            raise r.error(membrane, bad, msg) from None
        design = Design(rest, material)
        _read_ipams(r, root, design)
        _read_cells(r, membrane, design, UsdGeom)
    else:
        for extra in ("Ipams",):
            if root.GetChild(extra):
                raise r.error(root.GetChild(extra), None, "IPAMs need a Membrane prim next to them")

    targets, names = [], []
    tscope = root.GetChild("Targets")
    if tscope:
        for child in tscope.GetChildren():
            if not child.IsA(UsdGeom.Mesh):
                continue
            mesh, _ = r.triangles(child, f"{NS}:points", fallback="points")
            targets.append(mesh)
            names.append(child.GetName())

    settings = {}
    sprim = root.GetChild("Settings")
    if sprim:
        for a in sprim.GetAuthoredAttributes():
            name = a.GetName()
            if not name.startswith(f"{NS}:"):
                continue
            parts = name.split(":")
            if len(parts) != 3:
                raise r.error(sprim, name, f"settings attributes are named {NS}:<group>:<key>")
            tn = str(a.GetTypeName())
            v = a.Get()
            if tn == "bool":
                v = bool(v)
            elif tn in ("int", "int64", "uint", "uint64", "uchar"):
                v = int(v)
            elif tn in ("double", "float", "half"):
                v = float(v)
            elif tn in ("string", "token"):
                v = str(v)
            else:
                raise r.error(sprim, name, f"has type {tn}; settings are bool, int64, double or string")
            settings.setdefault(parts[1], {})[parts[2]] = v
    try:
        return Scene(design=design, targets=targets, target_names=names, settings=settings)
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None


def _read_ipams(r: _Reader, root, design: Design) -> None:
    prim = root.GetChild("Ipams")
    if not prim:
        return
    faces = r.int_array(prim, f"{NS}:faces", width=2)
    n = faces.shape[0]
    nf = design.rest.n_faces
    per = {}
    for key, width in (("stiffness", 1), ("area", 1), ("freeLength", 1), ("pressureLimits", 2), ("damping", 1)):
        a = r.float_array(prim, f"{NS}:{key}", width=width)
        if a.shape[0] != n:
            raise r.error(prim, f"{NS}:{key}", f"has {a.shape[0]} entries for {n} IPAMs ({NS}:faces)")
        per[key] = a
    bad = np.flatnonzero(((faces < 0) | (faces >= nf)).any(axis=1))
    if bad.size:
        i = int(bad[0])
        raise r.error(prim, f"{NS}:faces", f"IPAM {i} joins faces {faces[i].tolist()}, out of range: the "
                      f"membrane has {nf} faces")
    for i in range(n):
        try:
            design.add_ipam(int(faces[i, 0]), int(faces[i, 1]), stiffness=float(per["stiffness"][i]),
                            area=float(per["area"][i]), free_length=float(per["freeLength"][i]),
                            pressure_limits=tuple(float(p) for p in per["pressureLimits"][i]),
                            damping=float(per["damping"][i]))
        except DesignError as exc:
            raise r.error(prim, f"{NS}:faces", f"IPAM {i}: {exc}") from None


def _read_cells(r: _Reader, membrane, design: Design, UsdGeom) -> None:
    nf = design.rest.n_faces
    owner = np.full(nf, -1, dtype=np.int64)
    owner_path: list[str] = []
    for child in membrane.GetChildren():
        if not child.IsA(UsdGeom.Subset):
            continue
        fam = child.GetAttribute("familyName")
        if not fam or fam.Get() != CELL_FAMILY:
            continue
        et = r.token(child, "elementType", required=False)
        if et is not None and et != "face":
            raise r.error(child, "elementType", f"is {et!r}; a jamming cell is a set of faces (elementType face)")
        idx = r.int_array(child, "indices")
        if idx.size == 0:
            raise r.error(child, "indices", "a jamming cell needs at least one face")
        bad = idx[(idx < 0) | (idx >= nf)]
        if bad.size:
            raise r.error(child, "indices", f"face {int(bad[0])} is out of range: the membrane has {nf} faces")
        u = np.unique(idx)
        taken = owner[u] >= 0
        if np.any(taken):
            j = int(np.flatnonzero(taken)[0])
            raise r.error(child, "indices", f"face {int(u[j])} is already in cell <{owner_path[owner[u[j]]]}>; "
                          f"jamming cells may not overlap")
        try:
            c = design.add_cell(u)
        except DesignError as exc:
            raise r.error(child, "indices", str(exc)) from None
        owner[u] = c
        owner_path.append(str(child.GetPath()))


def load_scene(path_or_name) -> Scene:
    """Load a scene file, or a shipped scene by name (``list_scenes()``), validating everything.

    Errors are ``SceneError`` naming the file, the prim path and the attribute.
    """
    path = _resolve(path_or_name)
    stage = _open_stage(path)
    return read_stage(stage, str(path))


def validate_usd(path_or_stage) -> list[str]:
    """Run every registered ``pxr.UsdValidation`` validator; return the error messages (empty = valid)."""
    _pxr()
    from pxr import UsdValidation

    stage = path_or_stage
    if not hasattr(stage, "GetRootLayer"):
        stage = _open_stage(_resolve(path_or_stage))
    reg = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(reg.GetOrLoadAllValidators())
    return [e.GetErrorAsString() for e in ctx.Validate(stage) if not e.HasNoError()]
