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
    sin_t = wp.dot(wp.cross(n_a, n_b), e) / len_e
    cos_t = wp.dot(n_a, n_b)
    return wp.atan2(sin_t, cos_t)


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
    w, e = wp.tid()
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    length_out[w, e] = wp.length(x1 - x0)
    angle_out[w, e] = dihedral_angle(x0, x1, x_in[w, h[2]], x_in[w, h[3]])
