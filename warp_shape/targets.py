"""The paper's four target shapes: oval, pear, heart and cube (Figs. 11-13).

Every target is a closed, outward-wound ``TriMesh`` in metres, z up, centred on its volume
centroid, star-shaped from it, and scaled to ``DEFAULT_VOLUME`` (the volume of a 4 cm radius
sphere, the size of the paper's 8 cm device) unless ``volume=`` asks for another. Definitions,
in dimensionless shape units before the final centring and scaling (inside where f < 0):

- **oval**: the ellipsoid x^2/1.0^2 + y^2/0.9^2 + z^2/1.35^2 = 1 (three distinct semi-axes, so
  its orientation is well defined).
- **pear**: a smooth two-lobed body: the polynomial smooth union (blend k = 0.5) of the signed
  distances to a lower lobe (the ellipsoid with semi-axes 1, 0.85, 0.95 centred at the origin, its
  distance taken as (|(x/1, y/0.85, z/0.95)| - 1) * 0.85) and an upper lobe (sphere, radius 0.62,
  centre (0.3, 0, 1.1), leaning in +x like a real pear's neck), from which a concave dimple
  at the base is carved by the smooth difference (blend k = 0.12) with a sphere of radius 0.32 at
  (0, 0, -1.15). The waist between the lobes is saddle-shaped; the base dimple is a concave cup.
  Its only symmetry is the mirror y -> -y, so its pose is well defined.
- **heart**: Taubin's heart surface (x^2 + 9/4 y^2 + z^2 - 1)^3 - x^2 z^3 - 9/80 y^2 z^3 = 0: two
  lobes side by side along x with the cleft between them at the top (+z) and the point at the
  bottom (-z), flattened along y.
- **cube**: the cube [-1, 1]^3, faces meshed as regular grids so its edges and corners stay sharp.

Meshing: oval, pear and heart are sampled radially on a geodesic sphere of directions
(``icosphere(resolution)``: 20 * 4**resolution faces) from the shape's own volume centroid, found
by three rounds of sample -> centroid -> resample, so the mesh is star-shaped from its centroid by
construction; each vertex is the first zero of f along its ray, bracketed by marching and refined
by bisection to double precision. The cube uses an n x n grid per face with
n = 5 * 2**(resolution - 2) (12 n^2 faces; 4800 at the default resolution 4).
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

import numpy as np

from .errors import DesignError, MeshError, ShapeError, check_whole, read_input_file
from .mesh import TriMesh, icosphere

__all__ = ["TARGET_NAMES", "DEFAULT_VOLUME", "DEFAULT_RESOLUTION", "target", "write_targets", "centred_targets",
           "load_target", "check_mesh_file", "suggest", "is_identifier", "identifier_for"]

TARGET_NAMES = ("oval", "pear", "heart", "cube")
DEFAULT_VOLUME = 4.0 / 3.0 * np.pi * 0.04**3  # m^3, a 4 cm radius sphere (~2.68e-4)
DEFAULT_RESOLUTION = 4


# ---------------------------------------------------------------------------------------- implicit shapes
def _sphere(p, c, r):
    return np.linalg.norm(p - np.asarray(c, dtype=np.float64), axis=-1) - r


def _smooth_min(a, b, k):
    """Polynomial smooth minimum (smooth union of signed distances) with blend width k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1.0 - h) + a * h - k * h * (1.0 - h)


def _oval(p):
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return (x / 1.0) ** 2 + (y / 0.9) ** 2 + (z / 1.35) ** 2 - 1.0


def _ellipsoid(p, axes):
    """First-order signed distance to an origin-centred ellipsoid with these semi-axes."""
    axes = np.asarray(axes, dtype=np.float64)
    return (np.linalg.norm(p / axes, axis=-1) - 1.0) * axes.min()


def _pear(p):
    body = _smooth_min(_ellipsoid(p, (1.0, 0.85, 0.95)), _sphere(p, (0.3, 0.0, 1.1), 0.62), 0.5)
    dimple = _sphere(p, (0.0, 0.0, -1.15), 0.32)
    return -_smooth_min(-body, dimple, 0.12)  # smooth difference body \ dimple


def _heart(p):
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return (x * x + 2.25 * y * y + z * z - 1.0) ** 3 - x * x * z**3 - 0.1125 * y * y * z**3


_IMPLICIT = {"oval": _oval, "pear": _pear, "heart": _heart}


def _first_zero(f, center, dirs, t_max=3.0, marches=48, bisections=52):
    """Distance along each unit direction from ``center`` to the first sign change of f."""
    ts = np.linspace(0.0, t_max, marches + 1)
    vals = f(center + ts[:, None, None] * dirs[None])  # (marches+1, V)
    if np.any(vals[0] >= 0):
        raise ShapeError("internal: shape centre is not inside the shape")
    outside = vals > 0
    if not np.all(outside.any(axis=0)):
        raise ShapeError("internal: shape extends beyond the marching range")
    k = np.argmax(outside, axis=0)  # first sample outside
    lo, hi = ts[k - 1], ts[k]
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        out = f(center + mid[:, None] * dirs) > 0
        hi = np.where(out, mid, hi)
        lo = np.where(out, lo, mid)
    return 0.5 * (lo + hi)


def _radial_mesh(name: str, resolution: int) -> TriMesh:
    f = _IMPLICIT[name]
    sphere = icosphere(resolution, 1.0)
    dirs = sphere.vertices
    center = np.zeros(3)
    for _ in range(3):  # re-centre the rays on the volume centroid of the previous mesh
        mesh = TriMesh(center + _first_zero(f, center, dirs)[:, None] * dirs, sphere.faces, validate=False)
        center = mesh.centroid()
    return TriMesh(mesh.vertices, mesh.faces)


def _cube_mesh(resolution: int) -> TriMesh:
    n = max(1, int(round(5 * 2.0 ** (resolution - 2))))
    g = np.linspace(-1.0, 1.0, n + 1)
    a, b = np.meshgrid(g, g, indexing="ij")
    a, b = a.ravel(), b.ravel()
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    quads = np.stack([i, i + (n + 1), i + (n + 2), i + 1], axis=-1).reshape(-1, 4).ravel()
    verts, faces = [], []
    for axis in range(3):
        for side in (-1.0, 1.0):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            p = np.zeros((a.size, 3))
            p[:, axis], p[:, u], p[:, v] = side, a, b
            q = quads.reshape(-1, 4)
            tri = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
            # (u, v, axis) is right-handed; flip the winding on the negative side to face outward
            if side < 0:
                tri = tri[:, ::-1]
            faces.append(tri + sum(len(x) for x in verts))
            verts.append(p)
    v = np.concatenate(verts)
    f = np.concatenate(faces)
    # merge the vertices shared along the cube's edges (grid coordinates are exact repeats)
    uniq, inv = np.unique(np.round(v, 12), axis=0, return_inverse=True)
    return TriMesh(uniq, inv.reshape(-1)[f].astype(np.int32))


@lru_cache(maxsize=64)
def _build(name: str, volume: float, resolution: int) -> TriMesh:
    base = _cube_mesh(resolution) if name == "cube" else _radial_mesh(name, resolution)
    base = base.centered()
    mesh = base.scaled((volume / base.volume()) ** (1.0 / 3.0))
    v = mesh.vertices - mesh.centroid()  # remove rounding residue
    # coordinates that are zero by symmetry come out as +-1e-20 noise whose sign depends on the
    # summation order of the machine's numpy; make them exactly zero so shipped files reproduce
    v[np.abs(v) < 1e-12 * np.abs(v).max()] = 0.0
    return mesh.copy_with(v)


def target(name: str, volume: float | None = None, resolution: int = DEFAULT_RESOLUTION) -> TriMesh:
    """One of the paper's targets (``TARGET_NAMES``), centred on its volume centroid.

    ``volume`` (m^3) rescales it uniformly to exactly that volume (default ``DEFAULT_VOLUME``).
    ``resolution``: icosphere subdivisions of the direction mesh (20 * 4**resolution faces) or,
    for the cube, grid refinement (12 * (5 * 2**(resolution - 2))**2 faces); 1..6.
    """
    key = str(name).strip().lower()
    if key not in TARGET_NAMES:
        raise ShapeError(f"unknown target {name!r}; valid targets are {', '.join(TARGET_NAMES)}")
    vol = DEFAULT_VOLUME if volume is None else float(volume)
    if not (np.isfinite(vol) and vol > 0):
        raise ShapeError(f"target volume must be a positive finite number of m^3, got {volume}")
    res = check_whole(resolution, "target resolution", ShapeError)
    if not 1 <= res <= 6:
        raise ShapeError(f"target resolution must be in 1..6, got {resolution}")
    return _build(key, vol, res)


def centred_targets(targets, job: str, centre: bool = True) -> list[TriMesh]:
    """One target or a list of them as a list of meshes centred on their volume centroids (as given, where
    ``centre`` is False: they are centred already); a clear error (naming ``job``, e.g. "control") for an
    empty list or anything that is not a TriMesh."""
    if isinstance(targets, TriMesh):
        targets = [targets]
    if targets is None or isinstance(targets, (str, bytes)) or not hasattr(targets, "__iter__"):
        raise DesignError(f"{job} needs target shapes: a ws.TriMesh or a list of them (e.g. [ws.target('heart')]), "
                          f"got {targets!r}"[:300])
    targets = list(targets)
    if not targets:
        raise DesignError(f"{job} needs at least one target shape")
    for t in targets:
        if not isinstance(t, TriMesh):
            raise DesignError(f"targets must be ws.TriMesh (e.g. ws.target('heart')), got {type(t).__name__}")
    return [t.centered() for t in targets] if centre else targets


def write_targets(directory, *, fmt: str = "ply", resolution: int = DEFAULT_RESOLUTION) -> list[Path]:
    """Write every target at its default volume as ``directory/<name>.<fmt>``; return the paths."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in TARGET_NAMES:
        path = out / f"{name}.{fmt}"
        target(name, resolution=resolution).to_trimesh().export(str(path))
        paths.append(path)
    return paths


def suggest(name: str, known) -> str:
    """" (did you mean 'oval'?)" for the known name closest to ``name``, or ""."""
    import difflib

    close = difflib.get_close_matches(str(name).strip().lower(), [str(k) for k in known], n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _stl_problem(data: bytes) -> str | None:
    if len(data) >= 84:
        n = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * n and n > 0:
            return None  # binary STL
    head = data[:512].lstrip().lower()
    if head.startswith(b"solid") and b"\0" not in data[:4096] and b"facet" in data:
        return None  # ASCII STL
    if len(data) >= 84:
        n = int.from_bytes(data[80:84], "little")
        return (f"neither binary STL (84 + 50 x {n} triangles = {84 + 50 * n} bytes expected, the file has "
                f"{len(data)}) nor ASCII STL ('solid' ... 'facet' text)")
    return f"too short for an STL file ({len(data)} bytes)"


def _text_problem(data: bytes, kind: str, keys: tuple) -> str | None:
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        try:
            text = data.decode("latin-1") if b"\0" not in data else None
        except UnicodeDecodeError:
            text = None
        if text is None:
            return f"not a text {kind} file (binary bytes at offset {exc.start})"
    if not any(line.lstrip().startswith(keys) for line in text.splitlines()):
        return f"no {kind} vertex lines ({' / '.join(k.strip() for k in keys)}) found"
    return None


_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def is_identifier(name) -> bool:
    """True for a name that can be a USD prim name or part of an attribute name (a target's name is one)."""
    return isinstance(name, str) and bool(_IDENT.match(name))


def identifier_for(name: str) -> str:
    """``name`` made an identifier: every other character becomes ``_`` and a leading digit gets ``t_``
    (``my-oval`` -> ``my_oval``, ``3d scan`` -> ``t_3d_scan``); the name of a target read from a file."""
    out = re.sub(r"[^A-Za-z0-9_]", "_", str(name)) or "target"
    return out if is_identifier(out) else f"t_{out}"


def check_mesh_file(path) -> None:
    """A clear ``MeshError`` for a mesh file that is missing, empty or cannot be a mesh of its format
    (STL: binary size or ASCII text; OBJ: text with vertex lines); other formats are left to trimesh."""
    path = Path(path)
    data = read_input_file(path, "mesh file", MeshError)
    if not data:
        raise MeshError(f"could not parse mesh file {path}: the file is empty")
    ext = path.suffix.lower()
    problem = None
    if ext == ".stl":
        problem = _stl_problem(data)
    elif ext == ".obj":
        problem = _text_problem(data, "OBJ", ("v ",))
    if problem:
        raise MeshError(f"could not parse {ext[1:].upper()} file {path}: {problem}")


def load_target(spec: str) -> tuple[str, TriMesh]:
    """(name, mesh) of a target given by name (``TARGET_NAMES``) or as a mesh file, centred on its
    volume centroid; an unknown name that is no file says which names there are and the closest."""
    key = str(spec).strip().lower()
    if key in TARGET_NAMES:
        return key, target(key)
    path = Path(spec)
    if not path.exists() and not path.suffix:
        raise ShapeError(f"unknown target {spec!r}{suggest(spec, TARGET_NAMES)}; give a target name "
                         f"({', '.join(TARGET_NAMES)}) or a mesh file (STL, OBJ, PLY, ...)")
    check_mesh_file(path)
    try:
        return identifier_for(path.stem), TriMesh.load(path, center=True)
    except MeshError as exc:
        if "could not read" in str(exc):
            raise MeshError(f"could not parse mesh file {path}: {_reader_problem(exc.__cause__ or exc)}") from None
        raise


def _reader_problem(exc: BaseException) -> str:
    """What a mesh reader's exception says about the file, in words."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if isinstance(exc, ImportError) or "charset_normalizer" in text or isinstance(exc, UnicodeDecodeError):
        return "not text in a known encoding and not a binary mesh of its format (corrupt or mislabelled file)"
    if isinstance(exc, KeyError):
        return f"a field the format needs is missing ({text})"
    return text
