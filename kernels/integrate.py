"""Time integration, jamming and blow-up detection kernels (generic over float32/float64)."""

from typing import Any

import warp as wp

from .membrane import dihedral_angle, gauge_pressure, world_and_index


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
    """Flag blow-ups per world: non-finite or runaway positions (m) or speeds (m/s)."""
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


# --------------------------------------------------------------------------- fused-step integrators
#
# The fused force pass (membrane.eval_hinge*_kernel) leaves f (every force but pressure), dV/dx and
# the volume; these kernels add the pressure force p dV/dx, advance the state and start the next
# force evaluation (f = -c_v v at the next stage point, dV/dx = 0), so an RK4 step is
# init + 4 x (hinge pass [+ IPAM pass] + stage) launches.


@wp.kernel(enable_backward=False)
def rk4_stage_fused(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,)
    viscous_damping: Any,  # c_v, N s/m
    gas_rt: wp.float64,
    p_atm: wp.float64,
    h: Any,  # internal step, s
    stage: int,  # 0..3
    n_worlds: int,
    n_vertices: int,
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # In (the stage's force evaluation):
    f: wp.array2d(dtype=Any),  # (W, V) forces without pressure; reset for the next stage
    gradv: wp.array2d(dtype=Any),  # (W, V) dV/dx; zeroed for the next stage
    volume_in: wp.array2d(dtype=wp.float64),  # (W, 4) volume at each stage point
    v_eval: wp.array2d(dtype=Any),  # (W, V) velocity at the stage point
    # State in/out:
    x: wp.array2d(dtype=Any),  # (W, V)
    v: wp.array2d(dtype=Any),  # (W, V)
    # Scratch:
    xs: wp.array2d(dtype=Any),
    vs: wp.array2d(dtype=Any),
    acc_x: wp.array2d(dtype=Any),
    acc_v: wp.array2d(dtype=Any),
):
    """Classical RK4 on y = (x, v), y' = (v, f/m) with pressure applied here; controls held."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    p = gauge_pressure(air_in[w], volume_in[w, stage], gas_rt, p_atm)
    kx = v_eval[w, i]
    kv = (f[w, i] + gradv[w, i] * type(h)(p)) * inv_mass[i]
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
        v_next = v[w, i] + kv * c
        vs[w, i] = v_next
        f[w, i] = v_next * (-viscous_damping)
        gradv[w, i] = v_next * type(h)(0.0)
    else:
        sixth = h / type(h)(6.0)
        x[w, i] = x[w, i] + acc_x[w, i] * sixth
        v[w, i] = v[w, i] + acc_v[w, i] * sixth


@wp.kernel(enable_backward=False)
def integrate_semi_implicit_fused(
    inv_mass: wp.array(dtype=Any),  # (V,)
    gas_rt: wp.float64,
    p_atm: wp.float64,
    h: Any,
    n_worlds: int,
    n_vertices: int,
    air_in: wp.array(dtype=wp.float64),  # (W,)
    f_in: wp.array2d(dtype=Any),  # (W, V) forces without pressure
    gradv_in: wp.array2d(dtype=Any),  # (W, V)
    volume_in: wp.array2d(dtype=wp.float64),  # (W, slots), slot 0
    x: wp.array2d(dtype=Any),
    v: wp.array2d(dtype=Any),
):
    """Semi-implicit (symplectic) Euler with the pressure force applied here."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    p = gauge_pressure(air_in[w], volume_in[w, 0], gas_rt, p_atm)
    v_new = v[w, i] + (f_in[w, i] + gradv_in[w, i] * type(h)(p)) * (h * inv_mass[i])
    v[w, i] = v_new
    x[w, i] = x[w, i] + v_new * h
