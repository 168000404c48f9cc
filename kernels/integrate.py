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
    jam_stretch: Any,  # stretch stiffness multiplier
    jam_bend: Any,  # bending stiffness multiplier
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    # State out:
    edge: wp.array3d(dtype=Any),  # (4, W, E) rest length, rest angle, stretch and bending stiffness
    jammed: wp.array2d(dtype=wp.int32),  # (W, E)
):
    """Freeze an edge at its current length and angle and stiffen it; an edge already jammed keeps
    its values (a jam is applied once)."""
    w, j = wp.tid()
    if world_mask[w] == 0:
        return
    e = cell_edges[j]
    if jammed[w, e] != 0:
        return
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    edge[0, w, e] = wp.length(x1 - x0)
    edge[1, w, e] = dihedral_angle(x0, x1, x_in[w, h[2]], x_in[w, h[3]])
    edge[2, w, e] = edge[2, w, e] * jam_stretch
    edge[3, w, e] = edge[3, w, e] * jam_bend
    jammed[w, e] = 1


@wp.func
def flag_blowup(x: Any, v: Any, x_bound: Any, v_bound: Any, w: int, status_out: wp.array(dtype=wp.int32)):
    """Raise world w's status to this vertex's code if it is worse: 4 x non-finite, 3 v non-finite,
    2 x runaway (|x| > x_bound, m), 1 v runaway (|v| > v_bound, m/s); a sane vertex writes nothing."""
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
# The fused force pass (membrane.eval_hinge*_kernel) leaves the forces but pressure, dV/dx and the
# volume; these kernels add the pressure force p dV/dx, advance the state, flag blow-ups of the new
# state (worst code per world, read by the host after each output step) and start the next force
# evaluation (f = -c_v v at the next stage point, dV/dx = 0), so an RK4 step is
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
    x_bound: Any,  # |x| beyond this (m) is a blow-up
    v_bound: Any,  # |v| beyond this (m/s) is a blow-up
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # In (the stage's force evaluation):
    fg: wp.array3d(dtype=Any),  # (2, W, V) forces without pressure, dV/dx; reset for the next stage
    volume_in: wp.array2d(dtype=wp.float64),  # (W, 4) volume at each stage point
    # State in/out:
    xv: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities
    # Scratch:
    stage_xv: wp.array3d(dtype=Any),  # (2, W, V) the next stage point
    acc: wp.array3d(dtype=Any),  # (2, W, V) weighted sums of the stage slopes
    # Out:
    status_out: wp.array(dtype=wp.int32),  # (W,) worst blow-up code (see flag_blowup)
):
    """Classical RK4 on y = (x, v), y' = (v, f/m) with pressure applied here; controls held."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    p = gauge_pressure(air_in[w], volume_in[w, stage], gas_rt, p_atm)
    kx = xv[1, w, i]  # the velocity at the stage point
    if stage > 0:
        kx = stage_xv[1, w, i]
    kv = (fg[0, w, i] + fg[1, w, i] * type(h)(p)) * inv_mass[i]
    one = type(h)(1.0)
    two = type(h)(2.0)
    half = type(h)(0.5)
    if stage == 0:
        acc[0, w, i] = kx
        acc[1, w, i] = kv
    else:
        weight = two
        if stage == 3:
            weight = one
        acc[0, w, i] = acc[0, w, i] + kx * weight
        acc[1, w, i] = acc[1, w, i] + kv * weight
    if stage < 3:
        c = half * h
        if stage == 2:
            c = h
        stage_xv[0, w, i] = xv[0, w, i] + kx * c
        v_next = xv[1, w, i] + kv * c
        stage_xv[1, w, i] = v_next
        fg[0, w, i] = v_next * (-viscous_damping)
        fg[1, w, i] = v_next * type(h)(0.0)
    else:
        sixth = h / type(h)(6.0)
        x_new = xv[0, w, i] + acc[0, w, i] * sixth
        v_new = xv[1, w, i] + acc[1, w, i] * sixth
        xv[0, w, i] = x_new
        xv[1, w, i] = v_new
        flag_blowup(x_new, v_new, x_bound, v_bound, w, status_out)


@wp.kernel(enable_backward=False)
def integrate_semi_implicit_fused(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,)
    gas_rt: wp.float64,
    p_atm: wp.float64,
    h: Any,  # internal step, s
    n_worlds: int,
    n_vertices: int,
    x_bound: Any,  # |x| beyond this (m) is a blow-up
    v_bound: Any,  # |v| beyond this (m/s) is a blow-up
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # In:
    fg_in: wp.array3d(dtype=Any),  # (2, W, V) forces without pressure, dV/dx
    volume_in: wp.array2d(dtype=wp.float64),  # (W, slots), slot 0
    # State in/out:
    xv: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities
    # Out:
    status_out: wp.array(dtype=wp.int32),  # (W,) worst blow-up code (see flag_blowup)
):
    """Semi-implicit (symplectic) Euler with the pressure force applied here."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    p = gauge_pressure(air_in[w], volume_in[w, 0], gas_rt, p_atm)
    v_new = xv[1, w, i] + (fg_in[0, w, i] + fg_in[1, w, i] * type(h)(p)) * (h * inv_mass[i])
    x_new = xv[0, w, i] + v_new * h
    xv[1, w, i] = v_new
    xv[0, w, i] = x_new
    flag_blowup(x_new, v_new, x_bound, v_bound, w, status_out)
