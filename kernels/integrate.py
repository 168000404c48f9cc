"""Time integration kernels of the fused step: RK4 stages, semi-implicit Euler and blow-up flags.

The fused force pass (hinge.eval_hinge*_kernel) leaves the forces but pressure, dV/dx and the
volume; these kernels add the pressure force p dV/dx, advance the state, flag blow-ups of the new
state (worst code per world; on a GPU ``stamp_blowup_kernel`` notes after each output step the
first step at which a world's code became nonzero, so the host reads the codes only now and then)
and start the next force
evaluation (f = -c_v v at the next stage point, dV/dx = 0), so an RK4 step is
init + 4 x (hinge pass [+ IPAM pass] + stage) launches. Generic over float32/float64.
"""

from typing import Any

import warp as wp

from .common import world_and_index
from .pressure import gauge_pressure


@wp.func
def flag_blowup(
    x: Any,  # the vertex's new position, m
    v: Any,  # the vertex's new velocity, m/s
    x_bound: Any,  # m
    v_bound: Any,  # m/s
    w: int,  # world
    status_out: wp.array(dtype=wp.int32),  # (W,) worst code so far
):
    """Raise world w's status to this vertex's code if it is worse: 4 x non-finite, 3 v non-finite,
    2 x runaway (|x| > x_bound, m), 1 v runaway (|v| > v_bound, m/s); a sane vertex writes nothing.
    A finite sum of the six components proves them all finite (an inf or NaN makes the sum inf or
    NaN), so a sane vertex tests one value instead of six (each a library call on CPU)."""
    code = int(0)
    if wp.isfinite((x[0] + x[1] + x[2]) + (v[0] + v[1] + v[2])):
        if wp.length(x) > x_bound:
            code = 2
        elif wp.length(v) > v_bound:
            code = 1
    elif not (wp.isfinite(x[0]) and wp.isfinite(x[1]) and wp.isfinite(x[2])):
        code = 4
    elif not (wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])):
        code = 3
    elif wp.length(x) > x_bound:
        code = 2
    elif wp.length(v) > v_bound:
        code = 1
    if code > 0:
        wp.atomic_max(status_out, w, code)


@wp.kernel(enable_backward=False)
def stamp_blowup_kernel(
    # Control:
    step: int,  # the output step just taken
    # State in:
    status_in: wp.array(dtype=wp.int32),  # (W,) worst blow-up code so far (see flag_blowup)
    # Out:
    first_step_out: wp.array(dtype=wp.int32),  # (W,) output step at which the code became nonzero; -1 before
    first_code_out: wp.array(dtype=wp.int32),  # (W,) the code at that step
):
    """Note, per world, the first output step after which the blow-up code is nonzero."""
    w = wp.tid()
    code = status_in[w]
    if code != 0 and first_step_out[w] < 0:
        first_step_out[w] = step
        first_code_out[w] = code


@wp.kernel(enable_backward=False)
def rk4_stage_fused(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    viscous_damping: Any,  # c_v, N s/m
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    h: Any,  # internal step, s
    stage: int,  # 0..3
    n_worlds: int,
    n_vertices: int,
    x_bound: Any,  # |x| beyond this (m) is a blow-up
    v_bound: Any,  # |v| beyond this (m/s) is a blow-up
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # State in:
    volume_in: wp.array2d(dtype=wp.float64),  # (W, 4) volume at each stage point, m^3
    xv_in: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities at the start of the step (only read)
    # Out (read and updated):
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) the stage's forces without pressure, dV/dx; reset for the next stage
    xv_out: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities at the end of the step: written at the last stage
    scratch_out: wp.array3d(dtype=Any),  # (4, W, V) scratch: the next stage point (x, v), the weighted slope sums
    status_out: wp.array(dtype=wp.int32),  # (W,) worst blow-up code (see flag_blowup)
):
    """Classical RK4 on y = (x, v), y' = (v, f/m) with pressure applied here; controls held."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    p = gauge_pressure(air_in[w], volume_in[w, stage], gas_rt, p_atm)
    kx = xv_in[1, w, i]  # the velocity at the stage point
    if stage > 0:
        kx = scratch_out[1, w, i]
    kv = (fg_out[0, w, i] + fg_out[1, w, i] * type(h)(p)) * inv_mass[i]
    one = type(h)(1.0)
    two = type(h)(2.0)
    half = type(h)(0.5)
    if stage == 0:
        scratch_out[2, w, i] = kx
        scratch_out[3, w, i] = kv
    else:
        weight = two
        if stage == 3:
            weight = one
        scratch_out[2, w, i] = scratch_out[2, w, i] + kx * weight
        scratch_out[3, w, i] = scratch_out[3, w, i] + kv * weight
    if stage < 3:
        c = half * h
        if stage == 2:
            c = h
        scratch_out[0, w, i] = xv_in[0, w, i] + kx * c
        v_next = xv_in[1, w, i] + kv * c
        scratch_out[1, w, i] = v_next
        fg_out[0, w, i] = v_next * (-viscous_damping)
        fg_out[1, w, i] = v_next * type(h)(0.0)
    else:
        sixth = h / type(h)(6.0)
        x_new = xv_in[0, w, i] + scratch_out[2, w, i] * sixth
        v_new = xv_in[1, w, i] + scratch_out[3, w, i] * sixth
        xv_out[0, w, i] = x_new
        xv_out[1, w, i] = v_new
        flag_blowup(x_new, v_new, x_bound, v_bound, w, status_out)


@wp.kernel(enable_backward=False)
def integrate_semi_implicit_fused(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    h: Any,  # internal step, s
    n_worlds: int,
    n_vertices: int,
    x_bound: Any,  # |x| beyond this (m) is a blow-up
    v_bound: Any,  # |v| beyond this (m/s) is a blow-up
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # State in:
    fg_in: wp.array3d(dtype=Any),  # (2, W, V) forces without pressure (N), dV/dx (m^2)
    volume_in: wp.array2d(dtype=wp.float64),  # (W, slots) m^3, slot 0
    xv_in: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities at the start of the step (only read)
    # Out:
    xv_out: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities at the end of the step
    status_out: wp.array(dtype=wp.int32),  # (W,) worst blow-up code (see flag_blowup)
):
    """Semi-implicit (symplectic) Euler with the pressure force applied here."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    p = gauge_pressure(air_in[w], volume_in[w, 0], gas_rt, p_atm)
    v_new = xv_in[1, w, i] + (fg_in[0, w, i] + fg_in[1, w, i] * type(h)(p)) * (h * inv_mass[i])
    x_new = xv_in[0, w, i] + v_new * h
    xv_out[1, w, i] = v_new
    xv_out[0, w, i] = x_new
    flag_blowup(x_new, v_new, x_bound, v_bound, w, status_out)
