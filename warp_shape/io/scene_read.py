"""Read a USD scene file (or an open stage) back into a ``Scene``, validating every attribute.

Everything ``docs/scene_format.md`` describes is checked; a problem raises ``SceneError`` naming
the file, the prim path and the attribute. The attribute names and types come from the table in
``scene_schema``, the same one the writer uses.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..force_family import families
from ..designer import DesignSettings
from ..designer.run_settings import designer_fields
from ..display import Design
from ..errors import DesignError, MeshError, SceneError, read_input_file
from ..material import Material
from ..mesh import TriMesh
from ..simulation_settings import SimulationSettings
from .scene_registry import resolve_scene
from .scene_schema import (CELL_FAMILY, FORMAT_VERSION_ATTRIBUTE, MATERIAL_ATTRIBUTES,
                           MEMBRANE, NS, REST_POINTS, ROOT_NAME, SCENE_FORMAT_VERSION, SETTINGS, TARGET_POINTS,
                           TARGETS, Scene, SceneAttribute, material_attribute_for)
from .usd_common import load_pxr

__all__ = ["read_stage", "load_scene", "validate_usd", "load_actuated_shape"]

#: USD type names of settings attributes -> the Python type they read back as
SETTING_READERS = {"bool": bool, "int": int, "int64": int, "uint": int, "uint64": int, "uchar": int,
                   "double": float, "float": float, "half": float, "string": str, "token": str}


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

    def convert(self, prim, name: str, kind, value):
        """``kind(value)``; a value of another kind than its declared type (an edited layer can hold a
        list operation or a dictionary there) raises ``SceneError``."""
        try:
            return kind(value)
        except (TypeError, ValueError, OverflowError) as exc:
            raise self.error(prim, name, f"holds a {type(value).__name__}, not a value of its type ({exc})") from None

    def scalar(self, prim, name, required=True):
        numeric = {"double", "float", "half", "int", "int64", "uint", "uint64", "uchar"}
        _, v = self._typed(prim, name, required, lambda t: not t.isArray and str(t) in numeric, "a number (double)")
        if v is None:
            return None
        v = self.convert(prim, name, float, v)
        if not math.isfinite(v):
            raise self.error(prim, name, f"must be finite, got {v}")
        return v

    def int_array(self, prim, name, required=True, width=1):
        kinds = {1: {"int", "int64", "uint", "uint64"}, 2: {"int2"}}[width]
        what = "int[]" if width == 1 else "int2[]"
        _, v = self._typed(prim, name, required, lambda t: t.isArray and str(t.scalarType) in kinds, what)
        if v is None:
            return None
        a = self.convert(prim, name, lambda x: np.array(x, dtype=np.int64), v)
        if a.size % width:
            raise self.error(prim, name, f"has {a.size} numbers, not a whole number of {what} elements")
        return a.reshape(-1) if width == 1 else a.reshape(-1, width)

    def float_array(self, prim, name, required=True, width=1):
        kinds = {1: {"double", "float", "half"}, 2: {"double2", "float2", "half2"},
                 3: {"double3", "float3", "half3", "point3d", "point3f", "point3h", "vector3d", "vector3f",
                     "normal3d", "normal3f"}}[width]
        what = {1: "double[]", 2: "double2[]", 3: "point3d[] or point3f[]"}[width]
        _, v = self._typed(prim, name, required, lambda t: t.isArray and str(t.scalarType) in kinds, what)
        if v is None:
            return None
        a = self.convert(prim, name, lambda x: np.array(x, dtype=np.float64), v)
        if a.size % width:
            raise self.error(prim, name, f"has {a.size} numbers, not a whole number of {what} elements")
        a = a.reshape(-1) if width == 1 else a.reshape(-1, width)
        if not np.all(np.isfinite(a)):
            i = int(np.flatnonzero((~np.isfinite(a.reshape(a.shape[0], -1))).any(axis=1))[0])
            raise self.error(prim, name, f"element {i} is not finite: {a[i]}")
        return a

    def table_value(self, prim, attr: SceneAttribute):
        """The value of an attribute of the table: a float scalar, or an (n,) / (n, width) array."""
        if not attr.is_array:
            return self.scalar(prim, attr.name, attr.required)
        read = self.int_array if attr.is_integer else self.float_array
        return read(prim, attr.name, attr.required, width=attr.width)

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


def _message(exc: BaseException) -> str:
    """The text of an exception from USD, whatever bytes it holds (non-UTF-8 file content)."""
    try:
        text = str(exc)
    except Exception:  # its message is not decodable text
        text = f"{type(exc).__name__} with a message that is not UTF-8 text (binary or mis-encoded content)"
    return " ".join(text.split())[:500]


#: the most a compressed crate section can expand (LZ4's worst ratio is ~255)
CRATE_EXPANSION = 256
#: the most elements a crate section's byte can hold (2-bit integer codes, then LZ4)
CRATE_ELEMENTS_PER_BYTE = 4 * CRATE_EXPANSION


def check_crate(path: Path, data: bytes | None = None) -> None:
    """Refuse a binary (crate) USD file whose table of contents or element counts cannot be true for
    its size: USD believes such counts and allocates for them (a corrupt count of 1.5e9 tokens in a
    7 kB file took 40 s and 12 GB before USD reported it)."""
    import struct

    data = read_input_file(path, "scene", SceneError) if data is None else data
    if not data.startswith(b"PXR-USDC"):
        return
    size = len(data)

    def bad(what: str) -> SceneError:
        return SceneError(f"{path}: not a readable USD file (corrupt crate data: {what})")

    if size < 88:
        raise bad("shorter than its header")
    toc = struct.unpack_from("<q", data, 16)[0]
    if not 88 <= toc <= size - 8:
        raise bad(f"table of contents at byte {toc} of {size}")
    n = struct.unpack_from("<Q", data, toc)[0]
    if n > (size - toc - 8) // 32:
        raise bad(f"{n} sections in a table of {size - toc - 8} bytes")
    for i in range(n):
        name, start, length = struct.unpack_from("<16sqq", data, toc + 8 + 32 * i)
        name = name.rstrip(b"\0").decode("ascii", "replace")
        if start < 0 or length < 8 or start + length > size:
            raise bad(f"section {name} at bytes {start}..{start + length} of {size}")
        count = struct.unpack_from("<Q", data, start)[0]
        if count > CRATE_ELEMENTS_PER_BYTE * length:
            raise bad(f"section {name} claims {count} elements in {length} bytes")
        if name == "TOKENS" and length >= 24:
            _, raw, packed = struct.unpack_from("<QQQ", data, start)
            if count > raw or packed > length or raw > CRATE_EXPANSION * packed + 64:
                raise bad(f"{count} tokens in {raw} bytes, packed into {packed} of {length}")


#: the child process that reads a binary scene first: every layer it composes must be a regular file (a FIFO
#: would block USD; exit code 3 names it), then USD reads every attribute value of the stage
PROBE_SCRIPT = ("import os, resource, stat, sys\nlimit = int(sys.argv[2])\n"
                "resource.setrlimit(resource.RLIMIT_AS, (limit, limit))\n"
                "from pxr import Sdf, Usd\nseen = set()\n"
                "def walk(p):\n    seen.add(p)\n    layer = Sdf.Layer.FindOrOpen(p)\n"
                "    for dep in (layer.GetCompositionAssetDependencies() if layer else []):\n"
                "        full = layer.ComputeAbsolutePath(dep)\n"
                "        if full in seen or not os.path.exists(full):\n            continue\n"
                "        if not stat.S_ISREG(os.stat(full).st_mode):\n"
                "            sys.exit(f'composes {full}, which is not a regular file (a FIFO, device or folder)')\n"
                "        walk(full)\n"
                "walk(sys.argv[1])\nstage = Usd.Stage.Open(sys.argv[1])\n"
                "for prim in stage.Traverse():\n    for a in prim.GetAttributes():\n        a.Get()\n")
#: seconds the child may read a binary scene
PROBE_TIMEOUT = 120.0
#: address space of that child: a base for Python and USD plus a multiple of the file's size (bytes)
PROBE_MEMORY = 2 * 2**30
PROBE_MEMORY_PER_BYTE = 256


def probe_binary(path: Path, data: bytes | None = None) -> None:
    """Read a scene that is or composes binary (crate) USD in a child process first: USD can crash the
    process on corrupt crate data (a segmentation fault, no exception), which then happens there and
    becomes a ``SceneError``. Text-only scenes are not probed (USD parses text without crashing)."""
    import re
    import subprocess
    import sys

    data = read_input_file(path, "scene", SceneError) if data is None else data
    if not data.startswith(b"PXR-USDC") and not re.search(rb"@[^@\n]*\.usd[c]?@", data):
        return
    # corrupt counts make USD allocate tens of GB: the child's memory is bounded (a 4 MB scene needs ~100 MB)
    limit = PROBE_MEMORY + PROBE_MEMORY_PER_BYTE * len(data)
    try:
        run = subprocess.run([sys.executable, "-c", PROBE_SCRIPT, str(path), str(limit)], capture_output=True,
                             timeout=PROBE_TIMEOUT)
    except subprocess.TimeoutExpired:
        raise SceneError(f"{path}: USD did not finish reading the file in {PROBE_TIMEOUT:g} s (corrupt binary "
                         f"data?)") from None
    if run.returncode < 0:
        raise SceneError(f"{path}: not a readable USD file: USD crashed reading it (signal {-run.returncode}; "
                         f"corrupt binary crate data)")
    lines = run.stderr.decode("utf-8", "replace").strip().splitlines() or ["(no message)"]
    if run.returncode == 1 and lines[-1].startswith("composes "):
        raise SceneError(f"{path}: {lines[-1]}; give the files it composes as files saved on disk")
    if run.returncode != 0:
        raise SceneError(f"{path}: not a readable USD file (corrupt?): {' '.join(lines[-1].split())[:400]}")


def check_text_counts(path: Path, data: bytes) -> None:
    """Refuse a text layer holding more elements of an actuator family than a design holds, before USD
    parses it (USD took most of a minute over a scene of 100,000 IPAMs before the family refused them):
    the entries of the family's first attribute are counted in the text."""
    import re

    if data.startswith(b"PXR-USDC"):
        return
    for fam in families():
        if fam.max_count is None or not fam.scene_attributes:
            continue
        attr = fam.scene_attributes[0]
        for match in re.finditer(re.escape(attr.name.encode()) + rb"\s*=\s*\[", data):
            start, end = match.end(), data.find(b"]", match.end())
            end = len(data) if end < 0 else end
            n = data.count(b"(", start, end) if attr.width > 1 else \
                (data.count(b",", start, end) + 1 if data[start:end].strip() else 0)
            problem = fam.count_problem(n)
            if problem:
                raise SceneError(f"{path}: {attr.name}: {problem}")


#: how deep text layers composing text layers are followed before USD opens them
COMPOSED_DEPTH = 32


def check_composed_files(path: Path, data: bytes, seen: set | None = None) -> None:
    """Refuse a text scene that composes (sublayers, references, payloads: its ``@asset@`` paths, followed
    through the text layers they name) a file that is not a regular file: USD opens such a FIFO or device
    before any other check and blocks on it. Binary layers are walked by the probe (``probe_binary``)."""
    import re

    seen = set() if seen is None else seen
    seen.add(Path(path).resolve())
    if data.startswith(b"PXR-USDC") or len(seen) > COMPOSED_DEPTH:
        return
    for asset in dict.fromkeys(re.findall(rb"@([^@\n]+)@", data)):
        name = asset.decode("utf-8", "replace")
        full = Path(path).parent / name
        if "://" in name or not os.path.lexists(full) or full.resolve() in seen:
            continue
        try:
            layer = read_input_file(full, "layer", SceneError)
            check_text_counts(full, layer)
        except SceneError as exc:
            raise SceneError(f"{path}: composes @{name}@: {exc}") from None
        check_composed_files(full, layer, seen)


def _open_stage(path: Path, allow_outside: bool = False):
    """Open a scene file as a stage; unreadable files, composition errors and (unless
    ``allow_outside``) layers composed from outside the scene's folder raise ``SceneError``."""
    pxr = load_pxr()
    Sdf, Usd = pxr.Sdf, pxr.Usd
    data = read_input_file(path, "scene", SceneError)  # the file's bytes, checked before USD reads them
    check_crate(path, data)
    check_text_counts(path, data)
    check_composed_files(path, data)
    probe_binary(path, data)
    try:
        # a layer still open elsewhere under this identifier would be served stale: reload it
        existing = Sdf.Layer.Find(str(path))
        if existing:
            existing.Reload(force=True)
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # Tf.ErrorException, or undecodable bytes in a text layer
        raise SceneError(f"{path}: not a readable USD file (truncated or corrupt?): {_message(exc)}") from None
    if stage is None:
        raise SceneError(f"{path}: USD could not open the file")
    errors = stage.GetCompositionErrors() if hasattr(stage, "GetCompositionErrors") else []
    if errors:
        first = " ".join(str(errors[0]).split())
        raise SceneError(f"{path}: {len(errors)} composition error(s), first: {first} (a referenced file is "
                         f"missing? shipped problem scenes reference the target_<name>.usda files next to them)")
    if not allow_outside:
        _check_layers_inside(stage, path)
    return stage


def _check_layers_inside(stage, path: Path) -> None:
    """Refuse a scene that composes a layer (sublayer, reference, payload) from outside its own folder."""
    folder = Path(path).resolve().parent
    for layer in stage.GetUsedLayers():
        real = getattr(layer, "realPath", "") or ""
        if not real or layer.anonymous:
            continue
        try:
            Path(real).resolve().relative_to(folder)
        except ValueError:
            raise SceneError(f"{path}: composes {real}, outside the scene's folder {folder}; copy it next to the "
                             f"scene, or load with allow_outside=True if it is trusted") from None


def read_stage(stage, source: str = "<stage>") -> Scene:
    """Read a warp_shape scene from an open USD stage (see ``load_scene``)."""
    Tf = load_pxr().Tf
    r = _Reader(source)
    try:
        root = _scene_root(stage, r)
        design = _read_design(r, root)
        targets, names = _read_targets(r, root)
        settings = _read_settings(r, root)
    except (Tf.ErrorException, UnicodeDecodeError) as exc:  # a value USD cannot read (corrupt crate data)
        raise SceneError(f"{source}: a value could not be read (corrupt file?): {_message(exc)}") from None
    try:
        return Scene(design=design, targets=targets, target_names=names, settings=settings)
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None


def _scene_root(stage, r: _Reader):
    """The default prim, once the format version, up axis and unit are checked."""
    UsdGeom = load_pxr().UsdGeom
    source = r.source
    root = stage.GetDefaultPrim()
    if not root:
        raise SceneError(f"{source}: the stage has no defaultPrim; a warp_shape scene sets defaultPrim = "
                         f"\"{ROOT_NAME}\"", attribute="defaultPrim")
    version = r.scalar(root, FORMAT_VERSION_ATTRIBUTE)
    if version != SCENE_FORMAT_VERSION:
        raise r.error(root, FORMAT_VERSION_ATTRIBUTE, f"format version {version!r} is not supported "
                      f"(this build reads version {SCENE_FORMAT_VERSION}: set {FORMAT_VERSION_ATTRIBUTE} = "
                      f"{SCENE_FORMAT_VERSION})")
    up = UsdGeom.GetStageUpAxis(stage)
    if up != UsdGeom.Tokens.z:
        raise SceneError(f"{source}: upAxis is {up!r}; warp_shape scenes are Z-up", attribute="upAxis")
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    if mpu != 1.0:
        raise SceneError(f"{source}: metersPerUnit is {mpu}; warp_shape scenes are in metres (metersPerUnit = 1)",
                         attribute="metersPerUnit")
    return root


def _read_design(r: _Reader, root) -> Design | None:
    """The design under the default prim, or None when the scene has no Membrane."""
    UsdGeom = load_pxr().UsdGeom
    membrane = root.GetChild(MEMBRANE)
    if not membrane:
        for fam in families():
            if root.GetChild(fam.scene_prim):
                raise r.error(root.GetChild(fam.scene_prim), None,
                              f"{fam.plural} need a Membrane prim next to them")
        return None
    if not membrane.IsA(UsdGeom.Mesh):
        raise r.error(membrane, None, f"must be a Mesh, is a {membrane.GetTypeName() or 'typeless prim'}")
    design = Design(_read_rest(r, membrane), _read_material(r, membrane))
    for fam in families():
        _read_family(r, root, design, fam)
    _read_cells(r, membrane, design)
    return design


def _read_rest(r: _Reader, membrane) -> TriMesh:
    """The rest mesh: exact rest points (or the viewer points), which must agree with each other."""
    rest, used = r.triangles(membrane, REST_POINTS, fallback="points")
    if used != "points":  # the viewer points must agree with the exact rest points
        shown = r.float_array(membrane, "points", required=False, width=3)
        if shown is not None:
            tol = 1e-6 * float(np.abs(rest.vertices).max()) + 1e-9
            if shown.shape != rest.vertices.shape or np.abs(shown - rest.vertices).max() > tol:
                raise r.error(membrane, "points", f"disagrees with {REST_POINTS} (edited in another tool?); "
                              f"remove {REST_POINTS} to use the edited points")
    return rest


def _read_material(r: _Reader, membrane) -> Material:
    """Every Material field from its attribute; ``Material``'s own checks name the attribute."""
    values = {attr.field: (r.token(membrane, attr.name, attr.required) if attr.usd_type == "token"
                           else r.table_value(membrane, attr)) for attr in MATERIAL_ATTRIBUTES}
    values = {k: v for k, v in values.items() if v is not None}  # an optional field left out: its default
    try:
        return Material.from_dict(values)
    except DesignError as exc:
        msg = str(exc)
        raise r.error(membrane, material_attribute_for(msg), msg) from None


def _read_family(r: _Reader, root, design: Design, fam) -> None:
    """Add every element of an actuator family's prim to ``design`` (derived attributes are
    recomputed, not read); the family checks and adds them."""
    prim = root.GetChild(fam.scene_prim)
    if not prim:
        return
    first = fam.scene_attributes[0].name
    values = {}
    for attr in fam.scene_attributes:
        if not attr.required:
            continue
        a = r.table_value(prim, attr)
        n = next(iter(values.values())).shape[0] if values else a.shape[0]
        if a.shape[0] != n:
            raise r.error(prim, attr.name, f"has {a.shape[0]} entries for {n} {fam.plural} ({first})")
        values[attr.field] = a
    problem = fam.check_scene_values(design, values)
    if problem:
        raise r.error(prim, first, problem)
    for i in range(next(iter(values.values())).shape[0]):
        try:
            fam.add_from_scene(design, values, i)
        except DesignError as exc:
            raise r.error(prim, first, f"{fam.label} {i}: {exc}") from None


def _read_cells(r: _Reader, membrane, design: Design) -> None:
    """Add every jamming-cell subset of the membrane to ``design``, in prim order (no overlaps)."""
    UsdGeom = load_pxr().UsdGeom
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


def _read_targets(r: _Reader, root) -> tuple[list, list]:
    """Every Mesh under Targets, in order, with its prim name (another prim type there is an error)."""
    UsdGeom = load_pxr().UsdGeom
    targets, names = [], []
    scope = root.GetChild(TARGETS)
    if scope:
        for child in scope.GetChildren():
            if not child.IsA(UsdGeom.Mesh):
                raise r.error(child, None, f"is a {child.GetTypeName() or 'typeless prim'}, not a Mesh: every child "
                              f"of {TARGETS} is a target triangle mesh; make it a Mesh or move it out of {TARGETS}")
            mesh, _ = r.triangles(child, TARGET_POINTS, fallback="points")
            targets.append(mesh)
            names.append(child.GetName())
    return targets, names


def _read_settings(r: _Reader, root) -> dict:
    """``{group: {key: value}}`` from the ``warpShape:<group>:<key>`` attributes of Settings."""
    settings: dict = {}
    prim = root.GetChild(SETTINGS)
    if not prim:
        return settings
    for a in prim.GetAuthoredAttributes():
        name = a.GetName()
        if not name.startswith(f"{NS}:"):
            continue
        parts = name.split(":")
        if len(parts) != 3:
            raise r.error(prim, name, f"settings attributes are named {NS}:<group>:<key>")
        tn = str(a.GetTypeName())
        if tn not in SETTING_READERS:
            raise r.error(prim, name, f"has type {tn}; settings are bool, int64, double or string")
        value = a.Get() if a.HasAuthoredValue() else None
        if value is None:
            raise r.error(prim, name, "is declared without a value; give it one or remove it")
        settings.setdefault(parts[1], {})[parts[2]] = r.convert(prim, name, SETTING_READERS[tn], value)
    _check_setting_groups(r, prim, settings)
    return settings


def _check_setting_groups(r: _Reader, prim, settings: dict) -> None:
    """The groups this build reads, checked as they will be used: ``simulation`` as SimulationSettings
    (unknown keys and bad values), ``designer`` keys of DesignSettings and ``actuators`` by type."""
    try:
        SimulationSettings.from_dict(settings.get("simulation", {}))
    except DesignError as exc:
        raise r.error(prim, f"{NS}:simulation:*", str(exc)) from None
    designer = settings.get("designer", {})
    actuators = designer.get("actuators", 1)
    if isinstance(actuators, bool) or not isinstance(actuators, int) or actuators < 1:
        raise r.error(prim, f"{NS}:designer:actuators", f"must be an integer >= 1 (int64), got {actuators!r}")
    known = {k: v for k, v in designer.items() if k in DesignSettings.__dataclass_fields__}
    for key, value in known.items():
        default = getattr(DesignSettings(), key)
        if isinstance(default, (int, float)) and not isinstance(default, bool) and \
                (isinstance(value, (bool, str)) or not math.isfinite(value)):
            raise r.error(prim, f"{NS}:designer:{key}", f"must be a finite number, got {value!r}")
        if isinstance(default, (bool, str)) and type(value) is not type(default):
            raise r.error(prim, f"{NS}:designer:{key}", f"must be a {type(default).__name__}, got {value!r}")
    try:
        DesignSettings(**designer_fields(known))
    except (DesignError, TypeError) as exc:
        raise r.error(prim, f"{NS}:designer:*", str(exc)) from None


def load_scene(path_or_name, *, allow_outside: bool = False) -> Scene:
    """Load a scene file, or a shipped scene by name (``list_scenes()``), validating everything.

    Errors are ``SceneError`` naming the file, the prim path and the attribute. Sublayers,
    references and payloads must lie in the scene's folder (or below it) unless ``allow_outside``.
    """
    path = resolve_scene(path_or_name)
    stage = _open_stage(path, allow_outside)
    return read_stage(stage, str(path))


def validate_usd(path_or_stage) -> list[str]:
    """Run every registered ``pxr.UsdValidation`` validator; return the error messages (empty = valid)."""
    load_pxr()
    from pxr import UsdValidation

    stage = path_or_stage
    if not hasattr(stage, "GetRootLayer"):
        stage = _open_stage(resolve_scene(path_or_stage))
    reg = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(reg.GetOrLoadAllValidators())
    return [e.GetErrorAsString() for e in ctx.Validate(stage) if not e.HasNoError()]


def _animation_for(path: Path, stage, target: str | None) -> tuple[Path, object, str]:
    """The animated stage of ``target``'s controlled run: ``path`` itself when its membrane is animated,
    else (a design scene) the ``actuation_<target>.usdc`` a design or export wrote beside it."""
    root = stage.GetDefaultPrim()
    points = root.GetChild(MEMBRANE).GetAttribute("points") if root and root.GetChild(MEMBRANE) else None
    if points is None or not points.IsValid():
        raise SceneError(f"{path}: holds no membrane: give a design scene (design.usda) or an actuation_<target>.usdc")
    names = read_stage(stage, str(path)).target_names
    if points.GetNumTimeSamples() > 1:
        if target is not None and names and target not in names:
            raise SceneError(f"{path} is the run of target {names[0]}, not {target!r}")
        return path, stage, (names[0] if names else path.stem.removeprefix("actuation_"))
    if target is None:
        if len(names) != 1:
            raise SceneError(f"{path} is designed for {len(names)} targets ({', '.join(names) or 'none'}): "
                             f"name one with --target NAME")
        target = names[0]
    elif names and target not in names:
        raise SceneError(f"{path} has no target {target!r}; its targets: {', '.join(names)}")
    run = path.parent / f"actuation_{target}.usdc"
    if not run.is_file():
        raise SceneError(f"no {run.name} beside {path} (the simulated run of target {target}); write it with: "
                         f"warp-shape export {path} --what usd control --out {path.parent}")
    return run, _open_stage(run), target


def load_actuated_shape(path, *, target: str | None = None, time_s: float | None = None):
    """The membrane of a design's simulated, controlled run of ``target`` at ``time_s`` seconds of its
    valve schedule (None: the last sample, the achieved shape), as the run's ``actuation_<target>.usdc``
    recorded it. ``path``: that file, or the design scene (``design.usda``) it lies beside.
    Returns ``(TriMesh, info)``; info: ``target``, ``file``, ``time_s`` and ``duration_s``."""
    path = resolve_scene(path)
    run, stage, target = _animation_for(path, _open_stage(path), target)
    membrane = stage.GetDefaultPrim().GetChild(MEMBRANE)
    points = membrane.GetAttribute("points")
    tcps = float(stage.GetTimeCodesPerSecond())
    samples = points.GetTimeSamples()
    duration = float(samples[-1]) / tcps
    if time_s is None:
        time_s = duration
    if not (math.isfinite(time_s) and 0.0 <= time_s <= duration * (1 + 1e-9)):
        raise SceneError(f"--time {time_s:g} s lies outside the run of target {target} (0 to {duration:.4g} s of its "
                         f"valve schedule)")
    rest, _ = _Reader(str(run)).triangles(membrane, REST_POINTS, fallback="points")
    x = np.asarray(points.Get(load_pxr().Usd.TimeCode(min(time_s * tcps, float(samples[-1])))), dtype=np.float64)
    if x.shape != rest.vertices.shape or not np.all(np.isfinite(x)):
        raise SceneError(f"{run}: the membrane points at {time_s:g} s are not {rest.n_vertices} finite positions")
    return TriMesh(x, rest.faces), dict(target=target, file=str(run), time_s=float(time_s), duration_s=duration)
