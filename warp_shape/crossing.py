"""Whether a membrane passes through itself: the host side of ``kernels/crossing.py``.

``self_crossing`` finds, in one launch over a BVH of every world's faces, an edge that passes through
a face it does not touch; ``check_rest_mesh`` refuses a rest mesh that does (each mesh tested once),
and the simulator's tangle check (``Simulator.check_tangle``) uses it on the simulated state.
"""

from __future__ import annotations

import weakref

import numpy as np
import warp as wp

from warp_shape.kernels.crossing import edge_crossings

from .errors import MeshError
from .mesh import TriMesh

__all__ = ["self_crossing", "check_rest_mesh", "inward_fraction"]

#: rest meshes already found not to pass through themselves (each mesh is tested once)
_UNCROSSED: "weakref.WeakSet[TriMesh]" = weakref.WeakSet()


def self_crossing(positions, mesh: TriMesh, device=None) -> list[tuple[int, int, int, int]]:
    """(world, edge, face, crossing edges of that world) of every world whose surface passes through itself
    (edge: the first that crosses a face), empty where none does. ``positions``: (V, 3) or (W, V, 3)
    points of ``mesh``'s topology, m. One BVH over every world's faces and one launch of
    ``kernels.crossing.edge_crossings`` (an edge through a face it does not touch); about 10 ms for
    2562 vertices on a CPU."""
    x = np.asarray(positions, dtype=np.float64).reshape(-1, mesh.n_vertices, 3)
    worlds, nv = x.shape[0], mesh.n_vertices
    offset = (np.arange(worlds, dtype=np.int64) * nv)
    faces = (mesh.faces[None].astype(np.int64) + offset[:, None, None]).reshape(-1)
    edges = (mesh.edges[None].astype(np.int64) + offset[:, None, None]).reshape(-1, 2)
    device = wp.get_device(device)
    points = wp.array(x.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device=device)
    indices = wp.array(faces.astype(np.int32), dtype=wp.int32, device=device)
    bvh = wp.Mesh(points=points, indices=indices)
    crossed = wp.full(len(edges), -1, dtype=wp.int32, device=device)
    wp.launch(edge_crossings, dim=len(edges), device=device,
              inputs=[bvh.id, points, indices, wp.array(edges.astype(np.int32), dtype=wp.vec2i, device=device),
                      mesh.n_faces, len(mesh.edges)], outputs=[crossed])
    hit = crossed.numpy().reshape(worlds, -1)
    out = []
    for w in np.flatnonzero((hit >= 0).any(axis=1)):
        e = int(np.flatnonzero(hit[w] >= 0)[0])
        out.append((int(w), e, int(hit[w, e]), int(np.sum(hit[w] >= 0))))
    return out


def check_rest_mesh(rest: TriMesh) -> None:
    """A clear ``MeshError`` for a rest mesh that passes through itself (``self_crossing``): a membrane
    cannot be made or simulated so. Each mesh object is tested once."""
    if rest in _UNCROSSED or not np.all(np.isfinite(rest.vertices)):  # non-finite ones are refused elsewhere
        return
    found = self_crossing(rest.vertices, rest, device="cpu")
    if found:
        _, e, face, n = found[0]
        a, b = rest.edges[e]
        raise MeshError(f"the rest mesh passes through itself: edge ({a}, {b}) crosses face {face} ({n} crossing "
                        f"edges in all); a membrane must be a surface that does not intersect itself (repair it, "
                        f"e.g. remesh, before using it)")
    _UNCROSSED.add(rest)


def inward_fraction(x: np.ndarray, corners: tuple) -> np.ndarray:
    """(W,) fraction of each world's faces whose outward normal faces the world's centroid, at points
    x (W, V, 3) with ``corners`` the faces' three vertex columns (three (F,) index arrays): the cheap
    screen before ``self_crossing``. Components one by one (the same float operations as ``np.cross``
    and a sum over them, without their temporaries)."""
    a, b, c = (np.take(x, k, axis=1) for k in corners)
    out = a + b + c - 3.0 * x.mean(axis=1, keepdims=True)  # 3 x (face centroid - world centroid)
    u, v = b - a, c - a
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    dot = (u1 * v2 - u2 * v1) * out[..., 0] + (u2 * v0 - u0 * v2) * out[..., 1] + (u0 * v1 - u1 * v0) * out[..., 2]
    return np.mean(dot < 0, axis=1)
