"""Contact with rigid frictionless indenters, and the hold of a device at its plug.

An indenter j (a sphere of radius R_j, ``kind`` 0, or a flat plate, ``kind`` 1) moves along -u_j
(its unit axis, pointing out of the device) from its reference point o_j: at depth s (its control,
m) the sphere's centre, or a point of the plate's plane, is c = o_j - s u_j.

A sphere acts on the surface's faces: a face's point deepest inside it is q, the point of the face
closest to c (barycentric weights b_a, b_b, b_c), which penetrates by pen = R - |q - c|; the face
carries the penalty energy k pen^2 / 2, whose negative gradient is the force k pen (q - c) / |q - c| at q,
shared by the face's vertices in their weights b (the weights' own variation adds nothing: q
minimises the distance over the face). A plate acts on the vertices: the deepest point of a flat face
in a flat plate is one of its vertices; a vertex x penetrates by pen = (x - c) . u (the plate fills
(y - c) . u >= 0), carries k pen^2 / 2 and feels -k pen u. A held vertex is tied to its point p by a
zero-length spring: energy k |x - p|^2 / 2, force -k (x - p). Every kernel here but the
preconditioners' has an adjoint.
"""

from typing import Any

import warp as wp

KIND_SPHERE = wp.constant(0)
KIND_PLATE = wp.constant(1)


@wp.func
def closest_weights(p: Any, a: Any, b: Any, c: Any):
    """Barycentric weights (of a, b, c) of the point of triangle abc closest to p (Ericson's regions)."""
    a0 = a[0]
    one = type(a0)(1.0)
    zero = type(a0)(0.0)
    ab = b - a
    ac = c - a
    d1 = wp.dot(ab, p - a)
    d2 = wp.dot(ac, p - a)
    d3 = wp.dot(ab, p - b)
    d4 = wp.dot(ac, p - b)
    d5 = wp.dot(ab, p - c)
    d6 = wp.dot(ac, p - c)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    if d1 <= zero and d2 <= zero:
        return type(a)(one, zero, zero)
    if d3 >= zero and d4 <= d3:
        return type(a)(zero, one, zero)
    if d6 >= zero and d5 <= d6:
        return type(a)(zero, zero, one)
    if vc <= zero and d1 >= zero and d3 <= zero:
        t = d1 / (d1 - d3)
        return type(a)(one - t, t, zero)
    if vb <= zero and d2 >= zero and d6 <= zero:
        t = d2 / (d2 - d6)
        return type(a)(one - t, zero, t)
    if va <= zero and d4 - d3 >= zero and d5 - d6 >= zero:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return type(a)(zero, one - t, t)
    s = va + vb + vc
    return type(a)(va / s, vb / s, vc / s)


@wp.func
def indenter_push(
    kind: int,
    axis: Any,  # unit axis u, out of the device
    centre: Any,  # sphere centre / a point of the plate at the current depth, m
    radius: Any,  # m (sphere)
    stiffness: Any,  # N/m
    x: Any,  # vertex, m
):
    """Penalty force on vertex x (zero outside the indenter)."""
    zero = x * type(radius)(0.0)
    if kind == KIND_SPHERE:
        d = x - centre
        r = wp.length(d)
        pen = radius - r
        if pen > type(radius)(0.0) and r > type(radius)(0.0):
            return d * (stiffness * pen / r)
        return zero
    pen = wp.dot(x - centre, axis)
    if pen > type(radius)(0.0):
        return axis * (-stiffness * pen)
    return zero


@wp.kernel
def indenter_force_kernel(
    # Model:
    kind: wp.array(dtype=wp.int32),  # (n,) KIND_SPHERE or KIND_PLATE
    axis: wp.array(dtype=Any),  # (n,) unit axis u (out of the device)
    origin: wp.array(dtype=Any),  # (n,) reference point o at depth 0, m
    radius: wp.array(dtype=Any),  # (n,) m
    stiffness: wp.array(dtype=Any),  # (n,) penalty stiffness, N/m
    own: int,  # 1: world w holds indenter w only (n == W, a stiffness map); 0: every indenter in every world
    # Control:
    depth: wp.array2d(dtype=wp.float64),  # (W, n) m along -u from o
    enabled: wp.array2d(dtype=wp.int32),  # (W, n)
    # State in:
    x: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    f: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """Every enabled indenter's penalty force on every vertex of every world."""
    w, i = wp.tid()
    xi = x[w, i]
    lo = 0
    hi = kind.shape[0]
    if own != 0:
        lo = w
        hi = w + 1
    for j in range(lo, hi):
        if enabled[w, j] != 0 and kind[j] == KIND_PLATE:
            k = stiffness[j]
            c = origin[j] - axis[j] * type(k)(depth[w, j])
            wp.atomic_add(f, w, i, indenter_push(kind[j], axis[j], c, radius[j], k, xi))


@wp.kernel
def indenter_face_force_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,) vertex indices
    kind: wp.array(dtype=wp.int32),  # (n,) KIND_SPHERE or KIND_PLATE (plates: the vertex kernel)
    axis: wp.array(dtype=Any),  # (n,) unit axis u (out of the device)
    origin: wp.array(dtype=Any),  # (n,) sphere centre at depth 0, m
    radius: wp.array(dtype=Any),  # (n,) m
    stiffness: wp.array(dtype=Any),  # (n,) penalty stiffness per face, N/m
    own: int,  # 1: world w holds indenter w only; 0: every indenter in every world
    # Control:
    depth: wp.array2d(dtype=wp.float64),  # (W, n) m along -u from o
    enabled: wp.array2d(dtype=wp.int32),  # (W, n)
    # State in:
    x: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    f: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """Every enabled sphere's penalty force on every face of every world, at the face's point closest
    to its centre, shared by the face's vertices in that point's barycentric weights."""
    w, t = wp.tid()
    tri = faces[t]
    xa = x[w, tri[0]]
    xb = x[w, tri[1]]
    xc = x[w, tri[2]]
    lo = 0
    hi = kind.shape[0]
    if own != 0:
        lo = w
        hi = w + 1
    for j in range(lo, hi):
        if enabled[w, j] != 0 and kind[j] == KIND_SPHERE:
            k = stiffness[j]
            c = origin[j] - axis[j] * type(k)(depth[w, j])
            b = closest_weights(c, xa, xb, xc)
            push = indenter_push(kind[j], axis[j], c, radius[j], k, xa * b[0] + xb * b[1] + xc * b[2])
            wp.atomic_add(f, w, tri[0], push * b[0])
            wp.atomic_add(f, w, tri[1], push * b[1])
            wp.atomic_add(f, w, tri[2], push * b[2])


@wp.kernel(enable_backward=False)
def indenter_diagonal_kernel(
    # Model:
    kind: wp.array(dtype=wp.int32),  # (n,)
    axis: wp.array(dtype=Any),  # (n,)
    origin: wp.array(dtype=Any),  # (n,) m
    radius: wp.array(dtype=Any),  # (n,) m
    stiffness: wp.array(dtype=Any),  # (n,) N/m
    margin: Any,  # m: a vertex this close to an indenter counts as touching
    # Control:
    depth: wp.array2d(dtype=wp.float64),  # (W, n)
    enabled: wp.array2d(dtype=wp.int32),  # (W, n)
    # State in:
    x: wp.array2d(dtype=Any),  # (W, V)
    # Out:
    diag: wp.array2d(dtype=Any),  # (W, V) N/m, accumulated
):
    """The penalty stiffness on the preconditioner's diagonal of every vertex touching an indenter
    (within ``margin``) at the start of a settle."""
    w, i = wp.tid()
    xi = x[w, i]
    for j in range(kind.shape[0]):
        if enabled[w, j] != 0:
            k = stiffness[j]
            c = origin[j] - axis[j] * type(k)(depth[w, j])
            pen = wp.dot(xi - c, axis[j])
            if kind[j] == KIND_PLATE and pen > -margin:
                diag[w, i] = diag[w, i] + k


@wp.kernel(enable_backward=False)
def indenter_face_diagonal_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    kind: wp.array(dtype=wp.int32),  # (n,)
    axis: wp.array(dtype=Any),  # (n,)
    origin: wp.array(dtype=Any),  # (n,) m
    radius: wp.array(dtype=Any),  # (n,) m
    stiffness: wp.array(dtype=Any),  # (n,) N/m
    margin: Any,  # m: a face this close to a sphere counts as touching
    # Control:
    depth: wp.array2d(dtype=wp.float64),  # (W, n)
    enabled: wp.array2d(dtype=wp.int32),  # (W, n)
    # State in:
    x: wp.array2d(dtype=Any),  # (W, V)
    # Out:
    diag: wp.array2d(dtype=Any),  # (W, V) N/m, accumulated
):
    """A sphere's penalty stiffness k b^2 on the preconditioner's diagonal of the vertices of every face
    touching it (within ``margin``) at the start of a settle (b: the vertex's weight in the face's
    closest point)."""
    w, t = wp.tid()
    tri = faces[t]
    xa = x[w, tri[0]]
    xb = x[w, tri[1]]
    xc = x[w, tri[2]]
    for j in range(kind.shape[0]):
        if enabled[w, j] != 0 and kind[j] == KIND_SPHERE:
            k = stiffness[j]
            c = origin[j] - axis[j] * type(k)(depth[w, j])
            b = closest_weights(c, xa, xb, xc)
            if radius[j] - wp.length(xa * b[0] + xb * b[1] + xc * b[2] - c) > -margin:
                wp.atomic_add(diag, w, tri[0], k * b[0] * b[0])
                wp.atomic_add(diag, w, tri[1], k * b[1] * b[1])
                wp.atomic_add(diag, w, tri[2], k * b[2] * b[2])


@wp.kernel
def hold_force_kernel(
    # Model:
    vertex: wp.array(dtype=wp.int32),  # (n,) held vertices
    point: wp.array(dtype=Any),  # (n,) where each is held, m
    stiffness: wp.array(dtype=Any),  # (n,) N/m
    # State in:
    x: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    f: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """-k (x - p) on every held vertex of every world."""
    w, i = wp.tid()
    a = vertex[i]
    wp.atomic_add(f, w, a, (x[w, a] - point[i]) * (-stiffness[i]))


@wp.kernel(enable_backward=False)
def hold_diagonal_kernel(
    # Model:
    vertex: wp.array(dtype=wp.int32),  # (n,)
    stiffness: wp.array(dtype=Any),  # (n,) N/m
    # Out:
    diag: wp.array2d(dtype=Any),  # (W, V) N/m, accumulated
):
    """The hold's stiffness on the preconditioner's diagonal of its vertices."""
    w, i = wp.tid()
    a = vertex[i]
    diag[w, a] = diag[w, a] + stiffness[i]
