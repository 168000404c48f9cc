"""Time integration, jamming and blow-up detection kernels (generic over float32/float64)."""

from typing import Any

import warp as wp

from .membrane import dihedral_angle


@wp.kernel(enable_backward=False)
def integrate_semi_implicit(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    h: Any,  # internal step, s
    # In:
    f_in: wp.array2d(dtype=Any),  # (W, V) forces at (x, v)
    # State in/out:
    x: wp.array2d(dtype=Any),  # (W, V)
    v: wp.array2d(dtype=Any),  # (W, V)
):
    """Semi-implicit (symplectic) Euler: v += h f/m, then x += h v."""
    w, i = wp.tid()
    v_new = v[w, i] + f_in[w, i] * (h * inv_mass[i])
    v[w, i] = v_new
    x[w, i] = x[w, i] + v_new * h


@wp.kernel(enable_backward=False)
def rk4_stage(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,)
    h: Any,  # internal step, s
    stage: int,  # 0..3
    # In:
    f_in: wp.array2d(dtype=Any),  # (W, V) forces at the stage point
    v_eval: wp.array2d(dtype=Any),  # (W, V) velocity at the stage point
    # State in/out:
    x: wp.array2d(dtype=Any),  # (W, V) start of step; end of step after stage 3
    v: wp.array2d(dtype=Any),  # (W, V)
    # Scratch:
    xs: wp.array2d(dtype=Any),  # (W, V) next stage point
    vs: wp.array2d(dtype=Any),  # (W, V)
    acc_x: wp.array2d(dtype=Any),  # (W, V) weighted sum of slopes
    acc_v: wp.array2d(dtype=Any),  # (W, V)
):
    """Classical RK4 on y = (x, v), y' = (v, f/m); controls are held over the step."""
    w, i = wp.tid()
    kx = v_eval[w, i]
    kv = f_in[w, i] * inv_mass[i]
    one = type(h)(1.0)
    two = type(h)(2.0)
    half = type(h)(0.5)
    if stage == 0:
        acc_x[w, i] = kx
        acc_v[w, i] = kv
    else:
        weight = two
        if stage == 3:
            weight = one
        acc_x[w, i] = acc_x[w, i] + kx * weight
        acc_v[w, i] = acc_v[w, i] + kv * weight
    if stage < 3:
        c = half * h
        if stage == 2:
            c = h
        xs[w, i] = x[w, i] + kx * c
        vs[w, i] = v[w, i] + kv * c
    else:
        sixth = h / type(h)(6.0)
        x[w, i] = x[w, i] + acc_x[w, i] * sixth
        v[w, i] = v[w, i] + acc_v[w, i] * sixth


@wp.kernel(enable_backward=False)
def jam_edges_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,)
    cell_edges: wp.array(dtype=wp.int32),  # (n,) edges of the cell being jammed
    world_mask: wp.array(dtype=wp.int32),  # (W,) 1 for worlds that jam now
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    # State out:
    rest_length: wp.array2d(dtype=Any),  # (W, E)
    rest_angle: wp.array2d(dtype=Any),  # (W, E)
    jammed: wp.array2d(dtype=wp.int32),  # (W, E)
):
    """Freeze an edge at its current length and angle; an edge already jammed keeps its values."""
    w, j = wp.tid()
    if world_mask[w] == 0:
        return
    e = cell_edges[j]
    if jammed[w, e] != 0:
        return
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    rest_length[w, e] = wp.length(x1 - x0)
    rest_angle[w, e] = dihedral_angle(x0, x1, x_in[w, h[2]], x_in[w, h[3]])
    jammed[w, e] = 1


@wp.kernel(enable_backward=False)
def check_state_kernel(
    # Model:
    x_bound: Any,  # |x| beyond this (m) is a blow-up
    v_bound: Any,  # |v| beyond this (m/s) is a blow-up
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    v_in: wp.array2d(dtype=Any),  # (W, V)
    # Out:
    status_out: wp.array(dtype=wp.int32),  # (W,) worst code: 4 x non-finite, 3 v non-finite, 2 x runaway, 1 v runaway
):
    w, i = wp.tid()
    x = x_in[w, i]
    v = v_in[w, i]
    code = int(0)
    if not (wp.isfinite(x[0]) and wp.isfinite(x[1]) and wp.isfinite(x[2])):
        code = 4
    elif not (wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])):
        code = 3
    elif wp.length(x) > x_bound:
        code = 2
    elif wp.length(v) > v_bound:
        code = 1
    if code > 0:
        wp.atomic_max(status_out, w, code)
