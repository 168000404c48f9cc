"""Contact with rigid frictionless indenters, and the hold of a device at its plug.

An indenter j (a sphere of radius R_j, ``kind`` 0, or a flat plate, ``kind`` 1) moves along -u_j
(its unit axis, pointing out of the device) from its reference point o_j: at depth s (its control,
m) the sphere's centre, or a point of the plate's plane, is c = o_j - s u_j. A vertex x inside it
penetrates by pen = R - |x - c| (sphere) or pen = (x - c) . u (plate, which fills (y - c) . u >= 0)
and carries the penalty energy k pen^2 / 2, whose negative gradient is the force k pen (x - c) / |x - c|
(sphere) or -k pen u (plate). A held vertex is tied to its point p by a zero-length spring:
energy k |x - p|^2 / 2, force -k (x - p). Every kernel here but the preconditioner's has an adjoint.
"""

from typing import Any

import warp as wp

KIND_SPHERE = wp.constant(0)
KIND_PLATE = wp.constant(1)


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
        if enabled[w, j] != 0:
            k = stiffness[j]
            c = origin[j] - axis[j] * type(k)(depth[w, j])
            wp.atomic_add(f, w, i, indenter_push(kind[j], axis[j], c, radius[j], k, xi))


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
            if kind[j] == KIND_SPHERE:
                pen = radius[j] - wp.length(xi - c)
            if pen > -margin:
                diag[w, i] = diag[w, i] + k


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
