"""Edge springs with a damper along each edge (SPEC section 4): the force law and its kernel."""

from typing import Any

import warp as wp


@wp.func
def edge_frame(edge: Any):
    """(1 / |e|, |e|, e / |e|) of an edge vector, branch-free: a zero-length edge gets a zero
    direction through a floor on |e|^2 instead of a branch (cheaper than one in a serial CPU loop)."""
    ee = wp.dot(edge, edge)
    inv_len = type(ee)(1.0) / wp.sqrt(wp.max(ee, type(ee)(1.0e-30)))
    return inv_len, ee * inv_len, edge * inv_len


@wp.func
def spring_stretch_force(dhat: Any, length: Any, rest: Any, k: Any, damping: Any, dv: Any):
    """Force on the first end of a spring along dhat (length |d|, natural length rest, stiffness k)
    with a damper c along it, dv = v_j - v_i: [k (|d| - L) + c (v_j - v_i) . d_hat] d_hat."""
    return dhat * (k * (length - rest) + damping * wp.dot(dv, dhat))


@wp.func
def spring_damper_force(xi: Any, xj: Any, vi: Any, vj: Any, k: Any, rest: Any, c: Any):
    """Force on i of a spring (stiffness k, natural length rest) with a damper c along it; zero for
    coincident ends."""
    d = xj - xi
    length = wp.length(d)
    zero = type(k)(0.0)
    if length <= zero:
        return d * zero
    return spring_stretch_force(d / length, length, rest, k, c, vj - vi)


@wp.kernel(enable_backward=False)
def eval_spring_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    stiffness: wp.array(dtype=Any),  # (E,) k_e, N/m
    damping: Any,  # c_s, N s/m
    jam_factor: Any,  # stiffness multiplier of jammed edges
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    v_in: wp.array2d(dtype=Any),  # (W, V) m/s
    rest_length_in: wp.array2d(dtype=Any),  # (W, E) m
    jammed_in: wp.array2d(dtype=wp.int32),  # (W, E) 1 where jammed
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """Edge springs with a damper along each edge: f_i = [k (|d| - L) + c_s (v_j - v_i) . d_hat] d_hat."""
    w, e = wp.tid()
    h = hinges[e]
    k = stiffness[e]
    if jammed_in[w, e] != 0:
        k = k * jam_factor
    f = spring_damper_force(x_in[w, h[0]], x_in[w, h[1]], v_in[w, h[0]], v_in[w, h[1]], k, rest_length_in[w, e], damping)
    wp.atomic_add(f_out, w, h[0], f)
    wp.atomic_sub(f_out, w, h[1], f)
