"""Force kernels of the membrane model (SPEC section 4).

Every kernel is generic over the precision: positions/velocities are ``wp.vec3f`` or ``wp.vec3d``
and every scalar follows them. Worlds share one Model: State/Control arrays carry a leading world
dimension W and kernels launch over (W, n_elements). Forces are scattered with ``atomic_add``
(a plain add on CPU, so CPU runs are bit-for-bit deterministic).

Hinge convention (``hinges[e] = (v0, v1, v2, v3)``): the edge runs v0 -> v1 in face A = (v0, v1, v2)
and v1 -> v0 in face B = (v1, v0, v3). The signed dihedral angle is 0 for a flat hinge and
positive where the outward-wound surface is convex.
"""

from typing import Any

import warp as wp

# --------------------------------------------------------------------------- math helpers

@wp.func
def spring_damper_force(xi: Any, xj: Any, vi: Any, vj: Any, k: Any, rest: Any, c: Any):
    """Force on i of a spring (stiffness k, natural length rest) with a damper c along it."""
    d = xj - xi
    length = wp.length(d)
    zero = type(k)(0.0)
    if length <= zero:
        return d * zero
    dhat = d / length
    return dhat * (k * (length - rest) + c * wp.dot(vj - vi, dhat))


# atan(a) ~ a + a^3 P(a^2) on [0, 1]: a degree-7 minimax fit, |error| < 9e-8 rad in float32 arithmetic
# (float32 resolves 1.2e-7 rad at 1 rad). Inlined, it is 4x cheaper than a libm atan2f call, which
# also forces every live register of the hinge pass to be spilled around it.
_ATAN_POLY = (-0.3333297921, 0.1999021044, -0.1418445101, 0.10567944, -0.07354022783, 0.04097336247,
              -0.01504203915, 0.0025998325)


@wp.func
def hinge_atan2(y: wp.float32, x: wp.float32):
    """atan2(y, x) in float32 through the inlined polynomial (octant reduction, then atan on [0, 1])."""
    ax = wp.abs(x)
    ay = wp.abs(y)
    a = wp.min(ax, ay) / wp.max(wp.max(ax, ay), wp.float32(1.0e-30))
    s = a * a
    p = wp.float32(wp.static(_ATAN_POLY[7]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[6]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[5]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[4]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[3]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[2]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[1]))
    p = p * s + wp.float32(wp.static(_ATAN_POLY[0]))
    r = a + a * s * p
    r = wp.where(ay > ax, wp.float32(1.5707963267948966) - r, r)
    r = wp.where(x < wp.float32(0.0), wp.float32(3.141592653589793) - r, r)
    return wp.where(y < wp.float32(0.0), -r, r)


@wp.func
def hinge_atan2(y: wp.float64, x: wp.float64):
    """atan2(y, x) in float64: the library function (the polynomial would cost float64 accuracy)."""
    return wp.atan2(y, x)


@wp.func
def dihedral_angle(x0: Any, x1: Any, x2: Any, x3: Any):
    """Signed dihedral angle of hinge (v0, v1 | v2, v3); 0 flat, > 0 convex."""
    e = x1 - x0
    n_a = wp.cross(e, x2 - x0)
    n_b = wp.cross(x0 - x1, x3 - x1)
    len_e = wp.length(e)
    zero = type(len_e)(0.0)
    if len_e <= zero:
        return zero
    # (n_a x n_b) . e = -(n_a . (x3 - x0)) |e|^2; atan2 is scale invariant, so divide both by |e|
    return hinge_atan2(-wp.dot(n_a, x3 - x0) * len_e, wp.dot(n_a, n_b))


@wp.func
def wing_gradient(n: Any, len_e: Any):
    """d(theta)/d(wing vertex): -n_hat / h with h the wing's distance to the edge (n = 2 area n_hat)."""
    n2 = wp.dot(n, n)
    zero = type(len_e)(0.0)
    if n2 <= zero:
        return n * zero
    return n * (-len_e / n2)


@wp.func
def face_normal_area2(x0: Any, x1: Any, x2: Any):
    """Outward normal scaled by twice the face area."""
    return wp.cross(x1 - x0, x2 - x0)


# --------------------------------------------------------------------------- kernels


@wp.kernel(enable_backward=False)
def init_forces_viscous(
    # Model:
    viscous_damping: Any,
    # State in:
    v_in: wp.array2d(dtype=Any),  # (W, V)
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) overwritten with -c_v v
    volume_out: wp.array(dtype=wp.float64),  # (W,) zeroed for the volume pass
):
    """Start a force evaluation: viscous damping initialises the force array."""
    w, i = wp.tid()
    f_out[w, i] = v_in[w, i] * (-viscous_damping)
    if i == 0:
        volume_out[w] = wp.float64(0.0)


@wp.kernel(enable_backward=False)
def eval_volume_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    # Out:
    volume_out: wp.array(dtype=wp.float64),  # (W,) accumulated; zero it first
):
    """Enclosed volume by the divergence theorem, accumulated in float64 for every precision."""
    w, f = wp.tid()
    tri = faces[f]
    x0 = x_in[w, tri[0]]
    vol6 = wp.dot(x0, wp.cross(x_in[w, tri[1]], x_in[w, tri[2]]))
    wp.atomic_add(volume_out, w, wp.float64(vol6) / wp.float64(6.0))


@wp.kernel(enable_backward=False)
def eval_pressure_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    volume_in: wp.array(dtype=wp.float64),  # (W,) m^3
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) accumulated
):
    """Gauge pressure p = n R T / V - p_atm pushes each vertex of a face by p area / 3 n_hat."""
    w, f = wp.tid()
    tri = faces[f]
    x0 = x_in[w, tri[0]]
    n2a = face_normal_area2(x0, x_in[w, tri[1]], x_in[w, tri[2]])
    p = air_in[w] * gas_rt / volume_in[w] - p_atm
    force = n2a * type(x0[0])(p / wp.float64(6.0))
    wp.atomic_add(f_out, w, tri[0], force)
    wp.atomic_add(f_out, w, tri[1], force)
    wp.atomic_add(f_out, w, tri[2], force)


@wp.kernel(enable_backward=False)
def eval_spring_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,)
    stiffness: wp.array(dtype=Any),  # (E,) k_e, N/m
    damping: Any,  # c_s, N s/m
    jam_factor: Any,  # stiffness multiplier of jammed edges
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    v_in: wp.array2d(dtype=Any),  # (W, V)
    rest_length_in: wp.array2d(dtype=Any),  # (W, E)
    jammed_in: wp.array2d(dtype=wp.int32),  # (W, E) 1 where jammed
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) accumulated
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


@wp.kernel(enable_backward=False)
def eval_bending_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,)
    bending_stiffness: Any,  # k_t, N m/rad
    jam_factor: Any,  # bending multiplier of jammed edges
    paper_variant: int,  # 0: exact gradient; 1: paper eq. (9) edge forces
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    rest_angle_in: wp.array2d(dtype=Any),  # (W, E)
    jammed_in: wp.array2d(dtype=wp.int32),  # (W, E)
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) accumulated
):
    """Hinge springs, energy 0.5 k_t (theta - theta_0)^2."""
    w, e = wp.tid()
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    x2 = x_in[w, h[2]]
    x3 = x_in[w, h[3]]
    edge = x1 - x0
    len_e = wp.length(edge)
    zero = type(len_e)(0.0)
    if len_e <= zero:
        return
    kt = bending_stiffness
    if jammed_in[w, e] != 0:
        kt = kt * jam_factor
    torque = -kt * (dihedral_angle(x0, x1, x2, x3) - rest_angle_in[w, e])
    # wing forces: torque * d(theta)/d(wing)
    f2 = wing_gradient(wp.cross(edge, x2 - x0), len_e) * torque
    f3 = wing_gradient(wp.cross(x0 - x1, x3 - x1), len_e) * torque
    one = type(len_e)(1.0)
    if paper_variant != 0:
        half = type(len_e)(-0.5)
        f0 = (f2 + f3) * half
        f1 = f0
    else:
        # lever rule: a wing's reaction is split by where it projects onto the edge
        inv_e2 = one / (len_e * len_e)
        t2 = wp.dot(x2 - x0, edge) * inv_e2
        t3 = wp.dot(x3 - x0, edge) * inv_e2
        f1 = -(f2 * t2 + f3 * t3)
        f0 = -(f2 * (one - t2) + f3 * (one - t3))
    wp.atomic_add(f_out, w, h[0], f0)
    wp.atomic_add(f_out, w, h[1], f1)
    wp.atomic_add(f_out, w, h[2], f2)
    wp.atomic_add(f_out, w, h[3], f3)


@wp.kernel(enable_backward=False)
def eval_ipam_kernel(
    # Model:
    sub_pairs: wp.array(dtype=wp.vec2i),  # (3 n_ipam,) vertex of face a, vertex of face b
    sub_offsets: wp.array(dtype=Any),  # (3 n_ipam,) rest offset of each sub-spring, m
    stiffness: wp.array(dtype=Any),  # (n_ipam,) k, N/m
    area_over_k: wp.array(dtype=Any),  # (n_ipam,) A / k, m/Pa
    free_length: wp.array(dtype=Any),  # (n_ipam,) L0, m
    damping: wp.array(dtype=Any),  # (n_ipam,) N s/m per sub-spring
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    v_in: wp.array2d(dtype=Any),  # (W, V)
    # Control:
    pressure_in: wp.array2d(dtype=wp.float64),  # (W, n_ipam) gauge Pa
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) accumulated
):
    """IPAM as three sub-springs of stiffness k/3 and natural length L_n + offset, L_n = L0 + (A/k) P."""
    w, s = wp.tid()
    i = s // 3
    pair = sub_pairs[s]
    k = stiffness[i]
    natural = free_length[i] + area_over_k[i] * type(k)(pressure_in[w, i]) + sub_offsets[s]
    f = spring_damper_force(x_in[w, pair[0]], x_in[w, pair[1]], v_in[w, pair[0]], v_in[w, pair[1]],
                            k / type(k)(3.0), natural, damping[i])
    wp.atomic_add(f_out, w, pair[0], f)
    wp.atomic_sub(f_out, w, pair[1], f)


@wp.kernel(enable_backward=False)
def edge_state_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,)
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V)
    # Out:
    length_out: wp.array2d(dtype=Any),  # (W, E) current edge lengths
    angle_out: wp.array2d(dtype=Any),  # (W, E) current dihedral angles
):
    """Current edge lengths (m) and dihedral angles (rad), for jamming and read-outs."""
    w, e = wp.tid()
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    length_out[w, e] = wp.length(x1 - x0)
    angle_out[w, e] = dihedral_angle(x0, x1, x_in[w, h[2]], x_in[w, h[3]])


# --------------------------------------------------------------------------- fused step kernels
#
# The step evaluates every force family in one pass over the hinges (spring + damper, bending when
# k_t > 0, and the pressure's volume gradient), launched 1-D over W * n so that no thread pays for
# a 2-D index decomposition when there is one world. Pressure needs the enclosed volume before it
# can be applied, so the hinge pass accumulates the volume and dV/dx (gradv); the integrator stage
# kernel then adds p gradv with p = n R T / V - p_atm. Each face appears in three hinges (once per
# edge); the model gives it to one of them (Model.hinge_owns), which adds its whole contribution.


@wp.func
def world_and_index(t: int, n: int, n_worlds: int):
    """(world, element) of a 1-D thread index over n_worlds * n elements."""
    if n_worlds == 1:
        return 0, t
    w = t // n
    return w, t - w * n


@wp.func
def add_face_volume(
    n: Any,  # the face's outward normal times twice its area
    x_face: Any,  # any vertex of the face
    a: int,  # the face's vertices
    b: int,
    c: int,
    w: int,
    vslot: int,
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) row 1 += dV/dx
    volume_out: wp.array2d(dtype=wp.float64),  # (W, slots) += volume
):
    """Add one face's share of the enclosed volume (divergence theorem, x . n / 6) and its gradient
    n / 6 on each of its three vertices."""
    g = n * (type(x_face[0])(1.0) / type(x_face[0])(6.0))
    wp.atomic_add(volume_out, w, vslot, wp.float64(wp.dot(x_face, g)))
    wp.atomic_add(fg_out, 1, w, a, g)
    wp.atomic_add(fg_out, 1, w, b, g)
    wp.atomic_add(fg_out, 1, w, c, g)


def _make_hinge_kernel(name: str, with_bending: bool):
    """The fused per-hinge kernel, specialised at compile time with or without bending (k_t = 0
    designs launch the kernel whose name carries no 'bending' and that holds no bending code)."""

    def kernel(
        # Model:
        hinges: wp.array(dtype=wp.vec4i),  # (E,)
        owns: wp.array(dtype=wp.int32),  # (E,) bit 0 / 1: the hinge owns face A / B
        damping: Any,  # c_s, N s/m
        paper_variant: int,  # 0: exact gradient; 1: paper eq. (9) edge forces
        n_worlds: int,
        n_edges: int,
        # State in:
        edge_in: wp.array3d(dtype=Any),  # (4, W, E) rest length, rest angle, stretch and bending stiffness
        xv_in: wp.array3d(dtype=Any),  # (2, W, V) positions and velocities at the evaluation point
        vslot: int,  # column of volume_out to accumulate into
        # Out (accumulated):
        fg_out: wp.array3d(dtype=Any),  # (2, W, V) every force but pressure; dV/dx
        volume_out: wp.array2d(dtype=wp.float64),  # (W, slots) m^3
    ):
        w, e = world_and_index(wp.tid(), n_edges, n_worlds)
        h = hinges[e]
        x0 = xv_in[0, w, h[0]]
        x1 = xv_in[0, w, h[1]]
        edge = x1 - x0
        wing_a = xv_in[0, w, h[2]] - x0
        wing_b = xv_in[0, w, h[3]] - x0
        n_a = wp.cross(edge, wing_a)  # face A (v0, v1, v2): 2 area n_hat
        n_b = wp.cross(wing_b, edge)  # face B (v1, v0, v3)
        # Branch-free guards (the hinge pass runs as one serial loop on CPU, where a select is cheaper
        # than a branch): a zero-length edge or a zero-area wing yields zero force through the floor.
        one = type(damping)(1.0)
        tiny = type(damping)(1.0e-30)
        ee = wp.dot(edge, edge)
        inv_len = one / wp.sqrt(wp.max(ee, tiny))
        len_e = ee * inv_len
        dhat = edge * inv_len
        spring = edge_in[2, w, e] * (len_e - edge_in[0, w, e])
        fs = dhat * (spring + damping * wp.dot(xv_in[1, w, h[1]] - xv_in[1, w, h[0]], dhat))
        f0 = fs
        f1 = -fs
        f2 = edge * type(damping)(0.0)
        f3 = f2
        if wp.static(with_bending):
            # as in dihedral_angle: sin and cos both scaled by |n_a| |n_b|
            theta = hinge_atan2(-wp.dot(n_a, wing_b) * len_e, wp.dot(n_a, n_b))
            torque_l = edge_in[3, w, e] * (theta - edge_in[1, w, e]) * len_e  # -torque |e|
            f2 = n_a * (torque_l / wp.max(wp.dot(n_a, n_a), tiny))
            f3 = n_b * (torque_l / wp.max(wp.dot(n_b, n_b), tiny))
            if paper_variant != 0:
                fb1 = (f2 + f3) * type(damping)(-0.5)
            else:
                # lever rule: each wing's reaction split by where it projects onto the edge
                il2 = inv_len * inv_len
                fb1 = -(f2 * (wp.dot(wing_a, edge) * il2) + f3 * (wp.dot(wing_b, edge) * il2))
            f1 = f1 + fb1
            f0 = f0 - (f2 + f3 + fb1)  # the bending forces sum to zero
        wp.atomic_add(fg_out, 0, w, h[0], f0)
        wp.atomic_add(fg_out, 0, w, h[1], f1)
        if wp.static(with_bending):
            wp.atomic_add(fg_out, 0, w, h[2], f2)
            wp.atomic_add(fg_out, 0, w, h[3], f3)
        # pressure: each face's volume and dV/dx, added by the one hinge that owns the face
        own = owns[e]
        if own & 1:
            add_face_volume(n_a, x0, h[0], h[1], h[2], w, vslot, fg_out, volume_out)
        if own & 2:
            add_face_volume(n_b, x1, h[0], h[1], h[3], w, vslot, fg_out, volume_out)

    kernel.__name__ = kernel.__qualname__ = name
    return wp.kernel(kernel, enable_backward=False)


#: fused pass without bending (k_t = 0): spring + damper, volume and dV/dx
eval_hinge_kernel = _make_hinge_kernel("eval_hinge_kernel", False)
#: fused pass: spring + damper, hinge bending, volume and dV/dx
eval_hinge_bending_kernel = _make_hinge_kernel("eval_hinge_bending_kernel", True)


@wp.kernel(enable_backward=False)
def init_step_forces(
    viscous_damping: Any,
    n_worlds: int,
    n_vertices: int,
    # State in:
    xv_in: wp.array3d(dtype=Any),  # (2, W, V) positions, velocities
    # Out:
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) forces overwritten with -c_v v; dV/dx zeroed
    volume_out: wp.array2d(dtype=wp.float64),  # (W, slots) zeroed
):
    """Start the first force evaluation of a step (later RK4 stages are started by rk4 stage kernels)."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    v = xv_in[1, w, i]
    fg_out[0, w, i] = v * (-viscous_damping)
    fg_out[1, w, i] = v * type(viscous_damping)(0.0)
    if i == 0:
        for s in range(volume_out.shape[1]):
            volume_out[w, s] = wp.float64(0.0)


@wp.func
def gauge_pressure(air: wp.float64, volume: wp.float64, gas_rt: wp.float64, p_atm: wp.float64):
    return air * gas_rt / volume - p_atm


@wp.kernel(enable_backward=False)
def finish_forces_kernel(
    gas_rt: wp.float64,
    p_atm: wp.float64,
    n_worlds: int,
    n_vertices: int,
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    volume_in: wp.array2d(dtype=wp.float64),  # (W, slots)
    vslot: int,
    fg: wp.array3d(dtype=Any),  # (2, W, V) forces += p dV/dx
):
    """Add the pressure force p dV/dx of a fused evaluation (read-outs; steps do this in the stage kernel)."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    g = fg[1, w, i]
    p = gauge_pressure(air_in[w], volume_in[w, vslot], gas_rt, p_atm)
    fg[0, w, i] = fg[0, w, i] + g * type(g[0])(p)
