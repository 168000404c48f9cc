"""Closed triangle meshes: validation, topology and the icosphere.

A membrane (and every target) is a closed, 2-manifold, consistently and outward-wound triangle
mesh with finite vertices and no degenerate triangles. ``TriMesh`` checks all of that on
construction and raises ``MeshError`` naming the offending edge, face or vertex.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import MeshError, check_input_file, check_whole, numeric_array, read_input_file

__all__ = ["TriMesh", "EdgeTopology", "icosphere", "icosphere_like", "edge_topology"]

# A triangle whose area is below this fraction of (mean edge length)^2 counts as degenerate.
_DEGENERATE_REL_AREA = 1e-12


@dataclass(frozen=True)
class EdgeTopology:
    """Undirected edges of a closed mesh with their hinge (wing) vertices.

    ``hinges[e] = (v0, v1, v2, v3)``: the edge runs v0 -> v1 in face ``faces[e, 0]`` (whose third
    vertex is v2) and v1 -> v0 in face ``faces[e, 1]`` (third vertex v3). With outward winding the
    dihedral angle of the hinge is positive where the surface is convex.
    """

    hinges: np.ndarray  # (E, 4) int32
    faces: np.ndarray  # (E, 2) int32, face A (v0->v1) and face B (v1->v0)
    face_edges: np.ndarray  # (F, 3) int32, edge index of face edge (k, k+1)

    @property
    def edges(self) -> np.ndarray:
        """(E, 2) int32 vertex pairs."""
        return self.hinges[:, :2]

    @property
    def count(self) -> int:
        return int(self.hinges.shape[0])


def _edge_report(mesh_vertices: np.ndarray, a: int, b: int) -> str:
    pa = np.array2string(mesh_vertices[a], precision=4)
    pb = np.array2string(mesh_vertices[b], precision=4)
    return f"edge ({a}, {b}) between {pa} and {pb}"


def edge_topology(vertices: np.ndarray, faces: np.ndarray) -> EdgeTopology:
    """Build the hinge topology of a closed mesh, raising ``MeshError`` on any defect of the edges.

    Checks: every undirected edge has exactly two faces (else open boundary / non-manifold), and
    the two faces traverse it in opposite directions (else inconsistent winding).
    """
    faces = np.asarray(faces, dtype=np.int64)
    nf = faces.shape[0]
    # directed half-edges (k -> k+1) of every face
    src = faces.reshape(-1)
    dst = faces[:, [1, 2, 0]].reshape(-1)
    third = faces[:, [2, 0, 1]].reshape(-1)
    face_of = np.repeat(np.arange(nf), 3)
    lo = np.minimum(src, dst)
    hi = np.maximum(src, dst)
    nv = int(vertices.shape[0])
    key = lo * nv + hi
    order = np.argsort(key, kind="stable")
    skey = key[order]
    uniq, start, counts = np.unique(skey, return_index=True, return_counts=True)

    bad = np.flatnonzero(counts != 2)
    if bad.size:
        u = bad[0]
        a, b = divmod(int(uniq[u]), nv)
        faces_here = sorted(int(face_of[order[start[u] + j]]) for j in range(counts[u]))
        what = _edge_report(vertices, a, b)
        if counts[u] == 1:
            raise MeshError(
                f"mesh is not closed: open boundary at {what} (only face {faces_here[0]} uses it); "
                f"{int(np.sum(counts == 1))} boundary edge(s) in all. Close the holes (e.g. "
                f"trimesh.repair.fill_holes) before using it as a membrane or target."
            )
        raise MeshError(
            f"mesh is not 2-manifold: {what} is shared by {counts[u]} faces {faces_here}; "
            f"every edge of a closed membrane must have exactly two faces."
        )

    h0 = order[start]  # first half-edge of each undirected edge
    h1 = order[start + 1]
    same_dir = src[h0] == src[h1]
    if np.any(same_dir):
        u = int(np.flatnonzero(same_dir)[0])
        a, b = divmod(int(uniq[u]), nv)
        fa, fb = int(face_of[h0[u]]), int(face_of[h1[u]])
        raise MeshError(
            f"inconsistent winding: faces {fa} and {fb} both traverse {_edge_report(vertices, a, b)} "
            f"in the same direction; flip one of them so that neighbouring faces wind alike "
            f"(trimesh.repair.fix_winding)."
        )

    hinges = np.stack([src[h0], dst[h0], third[h0], third[h1]], axis=1).astype(np.int32)
    efaces = np.stack([face_of[h0], face_of[h1]], axis=1).astype(np.int32)
    face_edges = np.empty(nf * 3, dtype=np.int32)
    face_edges[order] = np.repeat(np.arange(uniq.size, dtype=np.int32), 2)
    return EdgeTopology(hinges=hinges, faces=efaces, face_edges=face_edges.reshape(nf, 3))


def _components(nv: int, edges: np.ndarray) -> int:
    """Number of connected components (union-find over edges, vectorized by pointer jumping)."""
    return int(np.unique(_component_labels(nv, edges)).size)


def _component_labels(nv: int, edges: np.ndarray) -> np.ndarray:
    """(nv,) the smallest node of each node's connected component (see ``_components``)."""
    parent = np.arange(nv)
    a, b = edges[:, 0].astype(np.int64), edges[:, 1].astype(np.int64)
    while True:
        pa, pb = parent[a], parent[b]
        lo = np.minimum(pa, pb)
        changed = False
        if np.any(pa != pb):
            np.minimum.at(parent, pa, lo)
            np.minimum.at(parent, pb, lo)
            changed = True
        # compress paths
        while True:
            gp = parent[parent]
            if np.array_equal(gp, parent):
                break
            parent = gp
        if not changed:
            break
    return parent


def pinched_vertex(faces: np.ndarray, topo: EdgeTopology) -> tuple[int, int] | None:
    """(vertex, fans) of the first vertex whose faces form more than one fan (two surfaces touching in one
    point: every edge has two faces, yet the mesh is not a 2-manifold there), or None. The face corners
    at a vertex are joined across each edge they share; a manifold vertex has one ring of them."""
    f = np.asarray(faces, dtype=np.int64)
    nf = f.shape[0]

    def corner(face, vertex):  # corner index 3 * face + k of ``vertex`` in ``face``
        return 3 * face + np.argmax(f[face] == vertex[:, None], axis=1)

    fa, fb = topo.faces[:, 0].astype(np.int64), topo.faces[:, 1].astype(np.int64)
    pairs = np.concatenate([np.stack([corner(fa, e), corner(fb, e)], 1) for e in topo.edges.T.astype(np.int64)])
    labels = _component_labels(3 * nf, pairs)
    vertex = f.reshape(-1)
    fans = np.bincount(np.unique(vertex * (3 * nf) + labels) // (3 * nf), minlength=int(vertex.max()) + 1)
    bad = np.flatnonzero(fans > 1)
    return (int(bad[0]), int(fans[bad[0]])) if bad.size else None


def _int_array(value) -> bool:
    """Whether ``value`` is (converts to) an array of integers (kept exact: no float round trip)."""
    try:
        return np.asarray(value).dtype.kind in "iu"
    except (ValueError, TypeError):
        return False


def regular_file_resolver(path):
    """A trimesh resolver for the files a mesh file names (an OBJ's ``mtllib``, a glTF's buffers), next to
    ``path``: each is read only if it is a regular file (``errors.read_input_file``); a FIFO there would
    block the read."""
    import os

    import trimesh.resolvers

    class Resolver(trimesh.resolvers.FilePathResolver):
        def get(self, name: str):
            for candidate in (name.strip(), name.strip().lstrip("/"), os.path.split(name)[-1]):
                try:
                    p = self.absolute(candidate)
                except ValueError:
                    continue
                if p.exists():
                    return read_input_file(p, f"file {name} that {path} names", MeshError)
            return super().get(name)

    return Resolver(str(path))


class TriMesh:
    """A validated closed triangle mesh.

    ``vertices``: (V, 3) float64 in metres. ``faces``: (F, 3) int32, wound counter-clockwise seen
    from outside (outward normals). Construction validates; pass ``validate=False`` only for meshes
    already known to be valid (e.g. a copy with moved vertices).
    """

    def __init__(self, vertices, faces, *, validate: bool = True):
        v = numeric_array(vertices, "vertices", MeshError)  # a new float64 array
        f = numeric_array(faces, "faces", MeshError) if not _int_array(faces) else np.array(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise MeshError(f"vertices must have shape (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise MeshError(f"faces must have shape (F, 3), got {f.shape}")
        if f.size and not np.issubdtype(f.dtype, np.integer):
            if not np.all(np.isfinite(f)) or not np.all(np.equal(np.mod(f, 1), 0)):
                raise MeshError("faces must hold integer vertex indices")
        if f.size and (f.min() < 0 or f.max() > np.iinfo(np.int32).max):  # checked before the int32 cast wraps
            fi = int(np.flatnonzero((f < 0).any(1) | (f > np.iinfo(np.int32).max).any(1))[0])
            raise MeshError(f"face {fi} {f[fi].astype(np.int64).tolist()} indexes a vertex outside "
                            f"0..{v.shape[0] - 1}")
        self.vertices = v
        self.faces = f.astype(np.int32)
        self.vertices.setflags(write=False)
        self.faces.setflags(write=False)
        self._topology: EdgeTopology | None = None
        if validate:
            self.validate()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def load(cls, path, *, center: bool = False, process: bool = True) -> "TriMesh":
        """Load any format trimesh reads (STL, OBJ, PLY, GLB, OFF, ...), merge duplicate vertices
        and validate. ``center=True`` moves the volume centroid to the origin."""
        path = Path(path)
        check_input_file(path, "mesh file", MeshError)
        try:
            import trimesh
        except ImportError as exc:  # pragma: no cover - trimesh is a dependency
            raise MeshError("reading mesh files needs trimesh (pip install trimesh)") from exc
        try:
            loaded = trimesh.load(str(path), force="mesh", process=False, resolver=regular_file_resolver(path))
            if not hasattr(loaded, "faces") or len(getattr(loaded, "faces", [])) == 0:
                raise MeshError(f"{path} holds no triangles")
            raw = np.asarray(loaded.vertices, dtype=np.float64)
            finite = np.all(np.isfinite(raw), axis=1)
            if not np.all(finite):  # before processing, which would drop it and report an open mesh
                i = int(np.flatnonzero(~finite)[0])
                raise MeshError(f"{path}: vertex {i} is not finite ({raw[i]}); every coordinate must be a "
                                f"finite number")
            if process:
                loaded = trimesh.Trimesh(loaded.vertices, loaded.faces, process=True)
        except MeshError:
            raise
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise MeshError(f"could not read mesh file {path}: {exc}") from exc
        try:
            mesh = cls(np.asarray(loaded.vertices), np.asarray(loaded.faces))
        except MeshError as exc:
            raise MeshError(f"{path}: {exc}") from None
        return mesh.centered() if center else mesh

    def copy_with(self, vertices) -> "TriMesh":
        """Same topology, new vertex positions (checked for shape and finiteness only)."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != self.vertices.shape:
            raise MeshError(f"new vertices have shape {v.shape}, expected {self.vertices.shape}")
        if not np.all(np.isfinite(v)):
            i = int(np.flatnonzero(~np.all(np.isfinite(v), axis=1))[0])
            raise MeshError(f"vertex {i} is not finite: {v[i]}")
        m = TriMesh(v, self.faces, validate=False)
        m._topology = self._topology
        return m

    def centered(self) -> "TriMesh":
        """A copy translated so its volume centroid is at the origin."""
        return self.copy_with(self.vertices - self.centroid())

    def scaled(self, factor: float) -> "TriMesh":
        """A copy with every vertex multiplied by ``factor`` (about the origin)."""
        return self.copy_with(self.vertices * float(factor))

    def to_trimesh(self):
        """The mesh as a ``trimesh.Trimesh`` (copied, not processed)."""
        import trimesh

        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        """Check the mesh (see the class docstring); raises ``MeshError`` naming the defect."""
        with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates: reported as a degenerate mesh
            self._validate()

    def _validate(self) -> None:
        v, f = self.vertices, self.faces
        nv = v.shape[0]
        if nv < 4 or f.shape[0] < 4:
            raise MeshError(f"a closed mesh needs at least 4 vertices and 4 faces, got {nv} and {f.shape[0]}")
        finite = np.all(np.isfinite(v), axis=1)
        if not np.all(finite):
            i = int(np.flatnonzero(~finite)[0])
            raise MeshError(f"vertex {i} is not finite ({v[i]}); every coordinate must be a finite number")
        if f.min() < 0 or f.max() >= nv:
            fi = int(np.flatnonzero((f < 0).any(1) | (f >= nv).any(1))[0])
            raise MeshError(f"face {fi} {f[fi].tolist()} indexes a vertex outside 0..{nv - 1}")
        rep = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
        if np.any(rep):
            fi = int(np.flatnonzero(rep)[0])
            raise MeshError(f"degenerate triangle: face {fi} {f[fi].tolist()} repeats a vertex")
        used = np.zeros(nv, dtype=bool)
        used[f.reshape(-1)] = True
        if not np.all(used):
            i = int(np.flatnonzero(~used)[0])
            raise MeshError(f"vertex {i} belongs to no face; remove unreferenced vertices first")
        area2 = np.linalg.norm(self._face_cross(), axis=1)
        e = v[f[:, [1, 2, 0]]] - v[f]
        scale = np.mean(np.linalg.norm(e, axis=2)) ** 2
        tiny = area2 <= 2.0 * _DEGENERATE_REL_AREA * scale
        if np.any(tiny):
            fi = int(np.flatnonzero(tiny)[0])
            raise MeshError(
                f"degenerate triangle: face {fi} {f[fi].tolist()} has (near) zero area "
                f"{0.5 * area2[fi]:.3e} m^2; remove or re-mesh collapsed triangles"
            )
        topo = edge_topology(v, f)
        ncomp = _components(nv, topo.edges)
        if ncomp != 1:
            raise MeshError(f"mesh has {ncomp} separate parts; a membrane or target must be one closed surface")
        pinched = pinched_vertex(f, topo)
        if pinched is not None:
            i, fans = pinched
            raise MeshError(f"mesh is not 2-manifold at vertex {i} {np.array2string(v[i], precision=4)}: its faces "
                            f"form {fans} separate fans (surfaces touching in one point); separate the surfaces or "
                            f"join them along a ring of edges")
        self._topology = topo
        vol = self.volume()
        if vol <= 0.0:
            raise MeshError(
                f"faces are wound inward (signed volume {vol:.3e} m^3 <= 0); reverse the winding "
                f"of every face (faces[:, ::-1]) so normals point outward"
            )

    # ------------------------------------------------------------------ geometry
    def _face_cross(self) -> np.ndarray:
        v, f = self.vertices, self.faces
        return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])

    @property
    def topology(self) -> EdgeTopology:
        """Hinge topology of the edges (built once, cached)."""
        if self._topology is None:
            self._topology = edge_topology(self.vertices, self.faces)
        return self._topology

    @property
    def edges(self) -> np.ndarray:
        """(E, 2) int32 vertex pairs of the undirected edges."""
        return self.topology.edges

    @property
    def n_vertices(self) -> int:
        """Number of vertices V."""
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of faces F."""
        return int(self.faces.shape[0])

    def face_areas(self) -> np.ndarray:
        """(F,) face areas in m^2."""
        return 0.5 * np.linalg.norm(self._face_cross(), axis=1)

    def face_normals(self) -> np.ndarray:
        """(F, 3) outward unit normals."""
        c = self._face_cross()
        return c / np.linalg.norm(c, axis=1, keepdims=True)

    def face_centroids(self) -> np.ndarray:
        """(F, 3) face centroids in m."""
        return self.vertices[self.faces].mean(axis=1)

    def area(self) -> float:
        """Surface area in m^2."""
        return float(self.face_areas().sum())

    def volume(self) -> float:
        """Enclosed (signed) volume in m^3, positive for outward winding."""
        v, f = self.vertices, self.faces
        return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)

    def centroid(self) -> np.ndarray:
        """Volume centroid (of the solid the mesh encloses)."""
        v, f = self.vertices, self.faces
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))
        total = vol6.sum()
        return (vol6[:, None] * (a + b + c)).sum(axis=0) / (4.0 * total)

    def vertex_areas(self) -> np.ndarray:
        """Area share of each vertex: 1/3 of the area of each adjacent face."""
        out = np.zeros(self.n_vertices)
        np.add.at(out, self.faces.reshape(-1), np.repeat(self.face_areas() / 3.0, 3))
        return out

    def face_adjacency(self) -> np.ndarray:
        """(F, 3) index of the face across each face edge."""
        topo = self.topology
        other = np.where(topo.faces[topo.face_edges, 0] == np.arange(self.n_faces)[:, None],
                         topo.faces[topo.face_edges, 1], topo.faces[topo.face_edges, 0])
        return other.astype(np.int32)

    def __repr__(self) -> str:
        return f"TriMesh(vertices={self.n_vertices}, faces={self.n_faces})"


def icosphere(subdivisions: int = 3, radius: float = 0.04, center=(0.0, 0.0, 0.0)) -> TriMesh:
    """Geodesic sphere: an icosahedron subdivided ``subdivisions`` times, projected to ``radius``.

    Vertex count is 10 * 4**subdivisions + 2 (642 for 3, 2562 for 4, 10242 for 5, 40962 for 6).
    """
    subdivisions = check_whole(subdivisions, "icosphere subdivisions", MeshError)
    if subdivisions < 0 or subdivisions > 8:
        raise MeshError(f"subdivisions must be in 0..8, got {subdivisions}")
    if isinstance(radius, (bool, np.bool_)) or not isinstance(radius, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(radius) and radius > 0):
        raise MeshError(f"radius must be a positive finite length in metres, got {radius!r}")
    center = numeric_array(center, "icosphere center", MeshError)
    if center.shape != (3,) or not np.all(np.isfinite(center)):
        raise MeshError(f"icosphere center must be a finite point (x, y, z) in metres, got {center.tolist()}")
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        nv = v.shape[0]
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        key = np.minimum(e[:, 0], e[:, 1]) * nv + np.maximum(e[:, 0], e[:, 1])
        uniq, inv = np.unique(key, return_inverse=True)
        a, b = np.divmod(uniq, nv)
        mid = v[a] + v[b]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = (nv + inv).reshape(3, -1)  # midpoints of edges 01, 12, 20 of every face
        v = np.concatenate([v, mid])
        f = np.concatenate([
            np.stack([f[:, 0], m[0], m[2]], 1), np.stack([f[:, 1], m[1], m[0]], 1),
            np.stack([f[:, 2], m[2], m[1]], 1), np.stack([m[0], m[1], m[2]], 1)])
    return TriMesh(v * float(radius) + center, f.astype(np.int32))


def icosphere_like(mesh: TriMesh, subdivisions: int) -> TriMesh:
    """The same membrane at another resolution: an icosphere of ``subdivisions`` (10 * 4**n + 2
    vertices) whose sphere holds ``mesh``'s volume (radius (3 V / 4 pi)^(1/3), m)."""
    radius = float(mesh.volume() * 3 / (4 * np.pi)) ** (1 / 3)
    return icosphere(subdivisions, radius)
