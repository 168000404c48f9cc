"""Self-crossing test of closed triangle meshes: an edge that passes through a face it does not touch.

A closed mesh that passes through itself has such an edge (the ends of two triangles' crossing lie on
edges). Candidate faces come from the ``wp.Mesh`` BVH (faces whose bounding box overlaps the edge's);
each is an exact segment-triangle test (Moller-Trumbore). Used on rest meshes (``Design``) and on the
simulated state (the simulator's tangle guard).
"""

import warp as wp


@wp.func
def segment_crosses(p0: wp.vec3, p1: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> bool:
    """Whether the segment p0-p1 passes through the interior of triangle abc (ends and rims excluded)."""
    d = p1 - p0
    e1 = b - a
    e2 = c - a
    pvec = wp.cross(d, e2)
    det = wp.dot(e1, pvec)
    scale = wp.length(d) * wp.length(wp.cross(e1, e2))
    hit = False
    if wp.abs(det) > 1.0e-6 * scale:  # not parallel to the plane (float32)
        inv = 1.0 / det
        tvec = p0 - a
        u = wp.dot(tvec, pvec) * inv
        qvec = wp.cross(tvec, e1)
        w = wp.dot(d, qvec) * inv
        t = wp.dot(e2, qvec) * inv
        eps = 1.0e-5
        hit = u > eps and w > eps and u + w < 1.0 - eps and t > eps and t < 1.0 - eps
    return hit


@wp.kernel
def edge_crossings(
    # Model:
    mesh: wp.uint64,  # BVH over every world's faces (W * F faces)
    points: wp.array(dtype=wp.vec3),  # (W * V,) positions, the mesh's points
    indices: wp.array(dtype=wp.int32),  # (W * F * 3,) face vertex indices, world w's offset by w * V
    edges: wp.array(dtype=wp.vec2i),  # (W * E,) edge vertex pairs, offset as the faces
    faces_per_world: int,
    edges_per_world: int,
    # Out:
    crossed: wp.array(dtype=wp.int32),  # (W * E,) a face of the same world the edge passes through, or -1
):
    e = wp.tid()
    i = edges[e][0]
    j = edges[e][1]
    p0 = points[i]
    p1 = points[j]
    world = e / edges_per_world
    query = wp.mesh_query_aabb(mesh, wp.min(p0, p1), wp.max(p0, p1))
    f = int(0)
    while wp.mesh_query_aabb_next(query, f):
        if f / faces_per_world == world:
            a = indices[3 * f]
            b = indices[3 * f + 1]
            c = indices[3 * f + 2]
            if a != i and a != j and b != i and b != j and c != i and c != j:
                if segment_crosses(p0, p1, points[a], points[b], points[c]):
                    crossed[e] = f - world * faces_per_world
