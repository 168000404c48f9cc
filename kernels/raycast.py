"""Ray and closest-point queries against target meshes (``wp.Mesh`` BVHs).

Used by radial sampling (section IV-A), the star-shape check and the ICP of scan comparison.
All rays start at the origin of the mesh's space: targets are centred on their volume centroid.
Face indices written by these kernels are >= 0 for a hit; ``RAY_MISS`` and ``RAY_NO_DIRECTION``
mark the two ways a radial ray can fail.
"""

import warp as wp

RAY_MISS = wp.constant(-1)  # no face hit, even along the jittered retry directions
RAY_NO_DIRECTION = wp.constant(-2)  # query point at the origin: the ray direction is undefined

# Retry directions around a ray that slipped between faces (a vertex or edge hit in float32).
_RETRIES = wp.constant(8)
_TWO_PI = wp.constant(6.283185307179586)


@wp.func
def perpendicular_basis(d: wp.vec3):
    """Two unit vectors completing the unit vector ``d`` to an orthonormal basis."""
    a = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(d[0]) > 0.9:
        a = wp.vec3(0.0, 1.0, 0.0)
    b1 = wp.normalize(wp.cross(d, a))
    b2 = wp.cross(d, b1)
    return b1, b2


@wp.func
def radial_cast(mesh_id: wp.uint64, origin: wp.vec3, d: wp.vec3, max_t: float, jitter: float):
    """Distance from ``origin`` along the unit direction ``d`` to the mesh, and the face hit.

    Returns ``(t, face)``; ``face == RAY_MISS`` when nothing is hit. A ray aimed exactly at a vertex
    or along an edge can slip through in float32; it is retried along ``_RETRIES`` directions
    tilted by ``jitter`` radians around ``d``, and the original ray is then intersected with the
    plane of the face the tilted ray hit, so the answer still lies on the original ray.
    """
    q = wp.mesh_query_ray(mesh_id, origin, d, max_t)
    t = float(0.0)
    face = int(RAY_MISS)
    if q.result:
        t = q.t
        face = q.face
    else:
        b1, b2 = perpendicular_basis(d)
        for k in range(_RETRIES):
            if face == RAY_MISS:
                ang = _TWO_PI * float(k) / float(_RETRIES)
                dj = wp.normalize(d + jitter * (wp.cos(ang) * b1 + wp.sin(ang) * b2))
                qj = wp.mesh_query_ray(mesh_id, origin, dj, max_t)
                if qj.result:
                    n = wp.normalize(qj.normal)
                    dn = wp.dot(d, n)
                    t = qj.t
                    # plane intersection unless the face is nearly parallel to the ray
                    if wp.abs(dn) > 1.0e-3:
                        t = wp.dot(dj * qj.t, n) / dn
                    face = qj.face
    return t, face


@wp.kernel(enable_backward=False)
def radial_sample_kernel(
    # Model:
    mesh_ids: wp.array(dtype=wp.uint64),  # (W,) target BVH of each world
    max_t: float,  # longest ray (m)
    jitter: float,  # tilt of the retry rays (rad)
    # In:
    points_in: wp.array2d(dtype=wp.vec3),  # (W, N) query points; ray from the origin through each
    # Out:
    hits_out: wp.array2d(dtype=wp.vec3),  # (W, N) hit on the target
    radii_out: wp.array2d(dtype=float),  # (W, N) |hit|
    faces_out: wp.array2d(dtype=wp.int32),  # (W, N) face hit, or RAY_MISS / RAY_NO_DIRECTION
    failures_out: wp.array(dtype=wp.int32),  # (1,) number of failed rays (accumulated)
):
    w, i = wp.tid()
    q = points_in[w, i]
    r = wp.length(q)
    face = int(RAY_NO_DIRECTION)
    t = float(0.0)
    d = wp.vec3(0.0, 0.0, 0.0)
    if r > 0.0:
        d = q / r
        t, face = radial_cast(mesh_ids[w], wp.vec3(0.0, 0.0, 0.0), d, max_t, jitter)
    faces_out[w, i] = face
    if face < 0:
        wp.atomic_add(failures_out, 0, 1)
        # never leave a plausible-looking value behind a failed ray
        t = wp.nan
    hits_out[w, i] = d * t
    radii_out[w, i] = t


@wp.kernel(enable_backward=False)
def count_crossings_kernel(
    # Model:
    mesh_id: wp.uint64,
    origin: wp.vec3,  # common start of every ray
    max_t: float,  # longest ray (m)
    jitter: float,  # tilt of the retry rays for the first crossing (rad)
    step: float,  # advance past each crossing before looking for the next (m)
    max_crossings: int,
    # In:
    dirs_in: wp.array(dtype=wp.vec3),  # (M,) unit ray directions
    # Out:
    counts_out: wp.array(dtype=wp.int32),  # (M,) surface crossings along the ray, capped
    entering_out: wp.array(dtype=wp.int32),  # (M,) 1 where the first crossing enters the solid
):
    i = wp.tid()
    d = dirs_in[i]
    count = int(0)
    entering = int(0)
    # first crossing: robust to vertex/edge hits, like radial sampling
    t, face = radial_cast(mesh_id, origin, d, max_t, jitter)
    if face >= 0:
        n = wp.mesh_eval_face_normal(mesh_id, face)
        if wp.dot(n, d) < 0.0:
            entering = 1
        # later crossings: restart just past the previous one (also skips the twin hit of an edge)
        count = int(1)
        t_acc = float(t + step)
        searching = bool(True)
        while searching and count < max_crossings:
            q = wp.mesh_query_ray(mesh_id, origin + d * t_acc, d, max_t)
            if q.result:
                count = count + 1
                t_acc = t_acc + q.t + step
            else:
                searching = False
    counts_out[i] = count
    entering_out[i] = entering


@wp.kernel(enable_backward=False)
def closest_points_kernel(
    # Model:
    mesh_id: wp.uint64,
    max_dist: float,  # search radius (m)
    # In:
    points_in: wp.array(dtype=wp.vec3),  # (N,) query points
    # Out:
    closest_out: wp.array(dtype=wp.vec3),  # (N,) closest point on the mesh surface
    normals_out: wp.array(dtype=wp.vec3),  # (N,) unit normal of the face it lies on
    dist_out: wp.array(dtype=float),  # (N,) distance to it; -1 where nothing lies within max_dist
):
    i = wp.tid()
    p = points_in[i]
    q = wp.mesh_query_point_no_sign(mesh_id, p, max_dist)
    if q.result:
        # closest point from the barycentrics of the closest face
        c = wp.mesh_eval_position(mesh_id, q.face, q.u, q.v)
        closest_out[i] = c
        normals_out[i] = wp.mesh_eval_face_normal(mesh_id, q.face)
        dist_out[i] = wp.length(c - p)
    else:
        closest_out[i] = p
        normals_out[i] = wp.vec3(0.0, 0.0, 0.0)
        dist_out[i] = -1.0


@wp.kernel(enable_backward=False)
def nearest_point_distance_kernel(
    # Model:
    grid: wp.uint64,  # hash grid built over points_in
    radius: float,  # search radius (m)
    skip_self: int,  # 1 when the queries are points_in itself (nearest *other* point)
    # In:
    points_in: wp.array(dtype=wp.vec3),  # (P,) the point set
    queries_in: wp.array(dtype=wp.vec3),  # (M,) query points
    # Out:
    dist_out: wp.array(dtype=float),  # (M,) distance to the nearest point; -1 if none within radius
):
    i = wp.tid()
    x = queries_in[i]
    best = radius
    found = int(0)
    query = wp.hash_grid_query(grid, x, radius)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        if skip_self == 0 or j != i:
            dj = wp.length(points_in[j] - x)
            if dj <= best:
                best = dj
                found = 1
    if found == 1:
        dist_out[i] = best
    else:
        dist_out[i] = -1.0
