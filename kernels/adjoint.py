"""Backward-enabled kernels of the differentiable replay (docs/gradients.md).

The step's own kernels (hinge, integrate, ipam, jamming) are forward-only and update scratch in
place, which an adjoint cannot run through. These kernels compute the same physics from the same
``@wp.func`` laws, each writing fresh output arrays (a kernel only accumulates into or overwrites
arrays it does not read), so Warp's generated adjoints give exact vector-Jacobian products; the fused
hinge pass's adjoint is written by hand (``hinge_adjoint_kernel``), and the tape kernels keep and
restore one internal step's intermediates. They live in their own Warp module: the forward step's
module and its build are unchanged.

One world (W = 1) per replay; arrays keep the world axis of the step's layout so the fused hinge
pass is shared. The model's parameters are built here too (edge rest values and stiffness, masses,
IPAM sub-spring offsets) from the rest positions, so the adjoint reaches the rest shape. The IPAM's
forces are not copied here: its family's own kernel (``kernels/ipam.eval_ipam_kernel``) is built a
second time, with its adjoint, in this module (``eval_ipam_grad_kernel``), and the replay launches it
through the family (``gradients/families.py``), as it does every other force family's own kernels.
"""

from typing import Any

import warp as wp

from .bending import bending_forces_at, dihedral_angle, hinge_angle
from .common import world_and_index
from . import ipam as kip
from .pressure import add_face_volume, gauge_pressure
from .springs import edge_frame, spring_damper_force, spring_stretch_force

MODULE = "warp_shape.kernels.adjoint"



@wp.kernel(enable_backward=False, module=MODULE)
def hinge_grad_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
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
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) every force but pressure (N); dV/dx (m^2)
    volume_out: wp.array2d(dtype=wp.float64),  # (W, slots) m^3
    # Out (the tape):
    angle_out: wp.array3d(dtype=Any),  # (slots, stages, E) the hinges' angles, rad
    slot_in: wp.array(dtype=wp.int32),  # (1,) the tape slot
    stage: int,  # the evaluation's stage in the step
):
    """The step's fused hinge pass (hinge.make_hinge_kernel with bending, W = 1) that also leaves each
    hinge's angle on the tape for ``hinge_adjoint_kernel`` (which then needs no atan2)."""
    e = wp.tid()
    h = hinges[e]
    x0 = xv_in[0, 0, h[0]]
    x1 = xv_in[0, 0, h[1]]
    edge = x1 - x0
    wing_a = xv_in[0, 0, h[2]] - x0
    wing_b = xv_in[0, 0, h[3]] - x0
    n_a = wp.cross(edge, wing_a)  # face A (v0, v1, v2): 2 area n_hat
    n_b = wp.cross(wing_b, edge)  # face B (v1, v0, v3)
    inv_len, len_e, dhat = edge_frame(edge)
    fs = spring_stretch_force(dhat, len_e, edge_in[0, 0, e], edge_in[2, 0, e], damping,
                              xv_in[1, 0, h[1]] - xv_in[1, 0, h[0]])
    theta = hinge_angle(n_a, n_b, wing_b, len_e)
    angle_out[slot_in[0], stage, e] = theta
    fb0, fb1, f2, f3 = bending_forces_at(theta, edge, wing_a, wing_b, n_a, n_b, inv_len, len_e, edge_in[3, 0, e],
                                         edge_in[1, 0, e], paper_variant)
    wp.atomic_add(fg_out, 0, 0, h[0], fs + fb0)
    wp.atomic_add(fg_out, 0, 0, h[1], fb1 - fs)
    wp.atomic_add(fg_out, 0, 0, h[2], f2)
    wp.atomic_add(fg_out, 0, 0, h[3], f3)
    own = owns[e]
    if own & 1:
        add_face_volume(n_a, x0, h[0], h[1], h[2], 0, vslot, fg_out, volume_out)
    if own & 2:
        add_face_volume(n_b, x1, h[0], h[1], h[3], 0, vslot, fg_out, volume_out)


@wp.func
def edge_frame_adjoint(edge: Any, inv_len: Any, len_bar: Any, dhat_bar: Any, inv_bar: Any):
    """The adjoint of springs.edge_frame: d(loss)/d(edge) from the adjoints of |e|, e / |e| and 1 / |e|
    (below the floor on |e|^2 the length's adjoint does not reach e . e, as the floor's max has it)."""
    ee = wp.dot(edge, edge)
    floor = type(ee)(1.0e-30)
    inv_bar = inv_bar + len_bar * ee + wp.dot(dhat_bar, edge)
    ee_bar = len_bar * inv_len
    if ee > floor:
        ee_bar = ee_bar - type(ee)(0.5) * inv_bar * (inv_len * inv_len * inv_len)  # d(ee^-1/2)/d(ee)
    return dhat_bar * inv_len + edge * (type(ee)(2.0) * ee_bar)


@wp.func
def stretch_adjoint(mu: Any, dhat: Any, length: Any, rest: Any, k: Any, damping: Any, dv: Any):
    """The adjoint of springs.spring_stretch_force with mu the adjoint of the force on the first end
    (minus that of the second): (d/d dhat, d/d length, d/d dv, d/d rest, d/d k)."""
    s = k * (length - rest) + damping * wp.dot(dv, dhat)
    sigma = wp.dot(mu, dhat)
    return mu * s + dv * (sigma * damping), sigma * k, dhat * (sigma * damping), -sigma * k, sigma * (length - rest)


@wp.func
def wing_force_adjoint(mu: Any, n: Any, torque_l: Any):
    """The adjoint of a wing force n torque_l / max(|n|^2, tiny) with mu its adjoint: (d/dn, d/d torque_l,
    1 / max(|n|^2, tiny))."""
    nn = wp.dot(n, n)
    tiny = type(nn)(1.0e-30)
    inv = type(nn)(1.0) / wp.max(nn, tiny)
    p = wp.dot(mu, n)
    n_bar = mu * (torque_l * inv)
    if nn > tiny:
        n_bar = n_bar - n * (type(nn)(2.0) * p * torque_l * inv * inv)
    return n_bar, p * inv, inv


@wp.func
def angle_adjoint(theta_bar: Any, n_a: Any, n_b: Any, wing_b: Any, len_e: Any):
    """The adjoint of bending.hinge_angle, atan2(-(n_a . wing_b) |e|, n_a . n_b): (d/d n_a, d/d n_b,
    d/d wing_b, d/d |e|); the float32 polynomial atan2 is differentiated as atan2."""
    c = wp.dot(n_a, wing_b)
    y = -c * len_e
    x = wp.dot(n_a, n_b)
    r2 = x * x + y * y
    y_bar = type(x)(0.0)
    x_bar = type(x)(0.0)
    if r2 > type(x)(0.0):
        s = theta_bar / r2
        y_bar = s * x
        x_bar = -s * y
    return n_b * x_bar - wing_b * (y_bar * len_e), n_a * x_bar, n_a * (-y_bar * len_e), -y_bar * c


@wp.func
def bending_adjoint(theta: Any, l0: Any, l1: Any, l2: Any, l3: Any, edge: Any, wing_a: Any, wing_b: Any, n_a: Any,
                    n_b: Any, inv_len: Any, len_e: Any, kt: Any, rest_angle: Any, paper_variant: int):
    """The adjoint of bending.hinge_bending_forces at angle theta with l0..l3 the adjoints of the four forces:
    (d/d edge, d/d wing_a, d/d wing_b, d/d n_a, d/d n_b, d/d inv_len, d/d len_e, d/d rest angle, d/d k_t),
    n_a and n_b taken as independent inputs (their dependence on the edge and wings is the caller's)."""
    zero = type(len_e)(0.0)
    torque_l = kt * (theta - rest_angle) * len_e
    m1 = l1 - l0
    ta = type(len_e)(0.5)
    tb = ta
    il2 = inv_len * inv_len
    if paper_variant == 0:
        ta = wp.dot(wing_a, edge) * il2
        tb = wp.dot(wing_b, edge) * il2
    na_bar, t_bar_a, inv_a = wing_force_adjoint(l2 - l0 - m1 * ta, n_a, torque_l)
    nb_bar, t_bar_b, inv_b = wing_force_adjoint(l3 - l0 - m1 * tb, n_b, torque_l)
    t_bar = t_bar_a + t_bar_b
    e_bar = edge * zero
    wa_bar = edge * zero
    wb_bar = edge * zero
    inv_bar = zero
    if paper_variant == 0:
        ta_bar = -wp.dot(m1, n_a) * (torque_l * inv_a)
        tb_bar = -wp.dot(m1, n_b) * (torque_l * inv_b)
        e_bar = (wing_a * ta_bar + wing_b * tb_bar) * il2
        wa_bar = edge * (ta_bar * il2)
        wb_bar = edge * (tb_bar * il2)
        inv_bar = type(len_e)(2.0) * inv_len * (ta_bar * wp.dot(wing_a, edge) + tb_bar * wp.dot(wing_b, edge))
    theta_bar = t_bar * kt * len_e
    na2, nb2, wb2, len_bar = angle_adjoint(theta_bar, n_a, n_b, wing_b, len_e)
    len_bar = len_bar + t_bar * kt * (theta - rest_angle)
    return (e_bar, wa_bar, wb_bar + wb2, na_bar + na2, nb_bar + nb2, inv_bar, len_bar, -theta_bar,
            t_bar * (theta - rest_angle) * len_e)


@wp.kernel(enable_backward=False, module=MODULE)
def hinge_adjoint_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    owns: wp.array(dtype=wp.int32),  # (E,) bit 0 / 1: the hinge owns face A / B
    damping: Any,  # c_s, N s/m
    paper_variant: int,  # 0: exact gradient; 1: paper eq. (9) edge forces
    n_worlds: int,
    n_edges: int,
    # State in (the forward pass's inputs):
    edge_in: wp.array3d(dtype=Any),  # (4, W, E) rest length, rest angle, stretch and bending stiffness
    xv_in: wp.array3d(dtype=Any),  # (2, W, V) positions and velocities at the evaluation point
    vslot: int,  # column of the volume
    # State in (adjoints of the forward pass's outputs):
    fg_adj: wp.array3d(dtype=Any),  # (2, W, V) adjoint of the forces (per N) and of dV/dx (per m^2)
    volume_adj: wp.array2d(dtype=wp.float64),  # (W, slots) adjoint of the volume, per m^3
    # Out (accumulated):
    edge_adj: wp.array3d(dtype=Any),  # (4, W, E) adjoint of the edge fields
    xv_adj: wp.array3d(dtype=Any),  # (2, W, V) adjoint of the positions and velocities
    # State in (the tape):
    angle_in: wp.array3d(dtype=Any),  # (slots, stages, E) the hinges' angles, rad
    slot_in: wp.array(dtype=wp.int32),  # (1,) the tape slot
    stage: int,  # the evaluation's stage in the step
):
    """The vector-Jacobian product of ``hinge_grad_kernel``'s pass: the adjoints of its inputs from
    those of its outputs, in one pass over the hinges as the forward's."""
    w, e = world_and_index(wp.tid(), n_edges, n_worlds)
    h = hinges[e]
    x0 = xv_in[0, w, h[0]]
    x1 = xv_in[0, w, h[1]]
    edge = x1 - x0
    wing_a = xv_in[0, w, h[2]] - x0
    wing_b = xv_in[0, w, h[3]] - x0
    n_a = wp.cross(edge, wing_a)
    n_b = wp.cross(wing_b, edge)
    inv_len, len_e, dhat = edge_frame(edge)
    l0 = fg_adj[0, w, h[0]]
    l1 = fg_adj[0, w, h[1]]
    dv = xv_in[1, w, h[1]] - xv_in[1, w, h[0]]
    dhat_bar, len_s, dv_bar, rest_bar, k_bar = stretch_adjoint(l0 - l1, dhat, len_e, edge_in[0, w, e],
                                                               edge_in[2, w, e], damping, dv)
    e_bar, wa_bar, wb_bar, na_bar, nb_bar, inv_bar, len_b, angle_bar, kt_bar = bending_adjoint(
        angle_in[slot_in[0], stage, e], l0, l1, fg_adj[0, w, h[2]], fg_adj[0, w, h[3]], edge, wing_a, wing_b, n_a,
        n_b, inv_len, len_e, edge_in[3, w, e], edge_in[1, w, e], paper_variant)
    # the faces' volume and dV/dx = n / 6 on their three vertices
    sixth = type(len_e)(1.0) / type(len_e)(6.0)
    lv = type(len_e)(volume_adj[w, vslot])
    x0_bar = edge * type(len_e)(0.0)
    x1_bar = x0_bar
    own = owns[e]
    g01 = fg_adj[1, w, h[0]] + fg_adj[1, w, h[1]]
    if own & 1:
        na_bar = na_bar + (g01 + fg_adj[1, w, h[2]] + x0 * lv) * sixth
        x0_bar = n_a * (lv * sixth)
    if own & 2:
        nb_bar = nb_bar + (g01 + fg_adj[1, w, h[3]] + x1 * lv) * sixth
        x1_bar = n_b * (lv * sixth)
    # n_a = edge x wing_a, n_b = wing_b x edge
    e_bar = e_bar + wp.cross(wing_a, na_bar) + wp.cross(nb_bar, wing_b)
    wa_bar = wa_bar + wp.cross(na_bar, edge)
    wb_bar = wb_bar + wp.cross(edge, nb_bar)
    e_bar = e_bar + edge_frame_adjoint(edge, inv_len, len_s + len_b, dhat_bar, inv_bar)
    wp.atomic_add(xv_adj, 0, w, h[0], x0_bar - e_bar - wa_bar - wb_bar)
    wp.atomic_add(xv_adj, 0, w, h[1], x1_bar + e_bar)
    wp.atomic_add(xv_adj, 0, w, h[2], wa_bar)
    wp.atomic_add(xv_adj, 0, w, h[3], wb_bar)
    wp.atomic_sub(xv_adj, 1, w, h[0], dv_bar)
    wp.atomic_add(xv_adj, 1, w, h[1], dv_bar)
    edge_adj[0, w, e] = edge_adj[0, w, e] + rest_bar
    edge_adj[1, w, e] = edge_adj[1, w, e] + angle_bar
    edge_adj[2, w, e] = edge_adj[2, w, e] + k_bar
    edge_adj[3, w, e] = edge_adj[3, w, e] + kt_bar


@wp.kernel(module=MODULE)
def build_edges_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    stretch_modulus: wp.array(dtype=Any),  # (1,) E t, N/m
    bending_stiffness: wp.array(dtype=Any),  # (1,) k_t, N m/rad
    wing_scale: wp.array2d(dtype=Any),  # (E, 2) multiplier of E t of face a (wing v2) and face b (wing v3)
    plate: wp.array(dtype=Any),  # (1,) D, N m: a hyperelastic membrane's plate stiffness
    hyperelastic: int,  # 1: the triangles carry the stretching (k_e = 0) and k_t = 3 D |e|^2 / A_e
    # State in:
    rest_in: wp.array(dtype=Any),  # (V,) rest positions, m
    # Out:
    edge_out: wp.array3d(dtype=Any),  # (4, 1, E) rest length, rest angle, stretch and bending stiffness
):
    """Each edge's rest length and angle, stretch stiffness E t (s_a A_a + s_b A_b) / L^2 and k_t at rest
    (model.host_model's, with a hyperelastic membrane: no stretch stiffness and the plate's hinge
    weighting of model.hinge_bend_stiffness)."""
    e = wp.tid()
    h = hinges[e]
    x0 = rest_in[h[0]]
    x1 = rest_in[h[1]]
    x2 = rest_in[h[2]]
    x3 = rest_in[h[3]]
    length = wp.length(x1 - x0)
    half = type(length)(0.5)
    area_a = half * wp.length(wp.cross(x1 - x0, x2 - x0))
    area_b = half * wp.length(wp.cross(x0 - x1, x3 - x1))
    area = wing_scale[e, 0] * area_a + wing_scale[e, 1] * area_b
    hyper = hyperelastic != 0
    edge_out[0, 0, e] = length
    edge_out[1, 0, e] = dihedral_angle(x0, x1, x2, x3)
    edge_out[2, 0, e] = wp.where(hyper, type(length)(0.0), stretch_modulus[0] * area / (length * length))
    edge_out[3, 0, e] = wp.where(hyper, type(length)(3.0) * plate[0] * length * length / (area_a + area_b),
                                 bending_stiffness[0])


@wp.kernel(module=MODULE)
def build_mass_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    areal_density: Any,  # kg/m^2
    # State in:
    rest_in: wp.array(dtype=Any),  # (V,) rest positions, m
    # Out:
    mass_out: wp.array(dtype=Any),  # (V,) kg, accumulated (zeroed first)
):
    """Lumped mass: a third of each adjacent face's area times the areal density."""
    f = wp.tid()
    t = faces[f]
    x0 = rest_in[t[0]]
    m = wp.length(wp.cross(rest_in[t[1]] - x0, rest_in[t[2]] - x0)) * areal_density / type(areal_density)(6.0)
    wp.atomic_add(mass_out, t[0], m)
    wp.atomic_add(mass_out, t[1], m)
    wp.atomic_add(mass_out, t[2], m)


@wp.kernel(module=MODULE)
def invert_kernel(
    # State in:
    a_in: wp.array(dtype=Any),  # (n,)
    # Out:
    inv_out: wp.array(dtype=Any),  # (n,) 1 / a
):
    """Element-wise reciprocal (masses into inverse masses)."""
    i = wp.tid()
    inv_out[i] = type(a_in[i])(1.0) / a_in[i]


@wp.kernel(module=MODULE)
def build_ipams_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    ipam_faces: wp.array(dtype=wp.vec2i),  # (n,) end faces a, b
    sub_pairs: wp.array(dtype=wp.vec2i),  # (3 n,) vertex of face a, vertex of face b
    free_fixed: wp.array(dtype=Any),  # (n,) L0 given, m; used where derived is 0
    derived: wp.array(dtype=wp.int32),  # (n,) 1 where L0 is the rest centroid distance
    stiffness: wp.array(dtype=Any),  # (n,) k, N/m
    area: wp.array(dtype=Any),  # (n,) A, m^2
    # State in:
    rest_in: wp.array(dtype=Any),  # (V,) rest positions, m
    # Out:
    offsets_out: wp.array(dtype=Any),  # (3 n,) sub-spring rest length minus the rest centroid distance, m
    free_out: wp.array(dtype=Any),  # (n,) L0, m
    area_over_k_out: wp.array(dtype=Any),  # (n,) A / k, m/Pa
):
    """The IPAM arrays that follow the rest shape and the sizes (Design.add_ipam's rule)."""
    s = wp.tid()
    i = s // 3
    fa = faces[ipam_faces[i][0]]
    fb = faces[ipam_faces[i][1]]
    third = type(area[i])(1.0) / type(area[i])(3.0)
    ca = (rest_in[fa[0]] + rest_in[fa[1]] + rest_in[fa[2]]) * third
    cb = (rest_in[fb[0]] + rest_in[fb[1]] + rest_in[fb[2]]) * third
    centre = wp.length(cb - ca)
    pair = sub_pairs[s]
    offsets_out[s] = wp.length(rest_in[pair[1]] - rest_in[pair[0]]) - centre
    if s - i * 3 == 0:
        if derived[i] != 0:
            free_out[i] = centre
        else:
            free_out[i] = free_fixed[i]
        area_over_k_out[i] = area[i] / stiffness[i]


@wp.kernel(module=MODULE)
def start_state_kernel(
    # State in:
    rest_in: wp.array(dtype=Any),  # (V,) rest positions, m
    # Out:
    xv_out: wp.array3d(dtype=Any),  # (2, 1, V) positions (the rest positions), velocities (zero)
):
    """The replay's first state: at rest."""
    i = wp.tid()
    x = rest_in[i]
    xv_out[0, 0, i] = x
    xv_out[1, 0, i] = x * type(x[0])(0.0)


@wp.kernel(module=MODULE)
def start_forces_kernel(
    # Model:
    viscous_damping: Any,  # c_v, N s/m
    # State in:
    xv_in: wp.array3d(dtype=Any),  # (2, 1, V) the evaluation point
    # Out:
    fg_out: wp.array3d(dtype=Any),  # (2, 1, V) forces overwritten with -c_v v (N); dV/dx zeroed (m^2)
    volume_out: wp.array2d(dtype=wp.float64),  # (1, 1) m^3, zeroed
):
    """Start one force evaluation."""
    i = wp.tid()
    v = xv_in[1, 0, i]
    fg_out[0, 0, i] = v * (-viscous_damping)
    fg_out[1, 0, i] = v * type(viscous_damping)(0.0)
    if i == 0:
        volume_out[0, 0] = wp.float64(0.0)


#: the IPAM family's sub-spring kernel (kernels/ipam.eval_ipam_kernel) built with its adjoint, for the
#: differentiable replay and the equilibrium gradient
eval_ipam_grad_kernel = wp.kernel(module=MODULE)(kip.eval_ipam_kernel.func)


@wp.func
def acceleration(fg: wp.array3d(dtype=Any), volume: wp.array2d(dtype=wp.float64), air: wp.array(dtype=wp.float64),
                 gas_rt: wp.float64, p_atm: wp.float64, inv_mass: Any, i: int):
    """(f + p dV/dx) / m of vertex i, p the gauge pressure of the evaluation's volume."""
    g = fg[1, 0, i]
    p = gauge_pressure(air[0], volume[0, 0], gas_rt, p_atm)
    return (fg[0, 0, i] + g * type(g[0])(p)) * inv_mass


@wp.kernel(module=MODULE)
def rk4_point_kernel(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    step_in: wp.array(dtype=Any),  # (1,) internal step h, s
    fraction: Any,  # the next stage point's share of h (1/2, 1/2, 1)
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (1,) mol
    # State in:
    xv_start: wp.array3d(dtype=Any),  # (2, 1, V) the step's first state
    xv_stage: wp.array3d(dtype=Any),  # (2, 1, V) this stage's point
    fg_in: wp.array3d(dtype=Any),  # (2, 1, V) this stage's forces without pressure, dV/dx
    volume_in: wp.array2d(dtype=wp.float64),  # (1, 1) this stage's volume, m^3
    # Out:
    accel_out: wp.array2d(dtype=Any),  # (1, V) this stage's acceleration, m/s^2
    xv_next: wp.array3d(dtype=Any),  # (2, 1, V) the next stage point
):
    """One RK4 stage: its slope (v, a) and the next point start + c (v, a)."""
    i = wp.tid()
    a = acceleration(fg_in, volume_in, air_in, gas_rt, p_atm, inv_mass[i], i)
    c = fraction * step_in[0]
    accel_out[0, i] = a
    xv_next[0, 0, i] = xv_start[0, 0, i] + xv_stage[1, 0, i] * c
    xv_next[1, 0, i] = xv_start[1, 0, i] + a * c


@wp.kernel(module=MODULE)
def rk4_combine_kernel(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    step_in: wp.array(dtype=Any),  # (1,) internal step h, s
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (1,) mol
    # State in:
    xv_start: wp.array3d(dtype=Any),  # (2, 1, V) the step's first state
    xv_1: wp.array3d(dtype=Any),  # (2, 1, V) stage points 1-3
    xv_2: wp.array3d(dtype=Any),
    xv_3: wp.array3d(dtype=Any),
    a_0: wp.array2d(dtype=Any),  # (1, V) accelerations of stages 0-2, m/s^2
    a_1: wp.array2d(dtype=Any),
    a_2: wp.array2d(dtype=Any),
    fg_3: wp.array3d(dtype=Any),  # (2, 1, V) the last stage's forces without pressure, dV/dx
    volume_3: wp.array2d(dtype=wp.float64),  # (1, 1) the last stage's volume, m^3
    # Out:
    xv_out: wp.array3d(dtype=Any),  # (2, 1, V) the state after the step
):
    """The RK4 step: start + h/6 (k0 + 2 k1 + 2 k2 + k3)."""
    i = wp.tid()
    h = step_in[0]
    a3 = acceleration(fg_3, volume_3, air_in, gas_rt, p_atm, inv_mass[i], i)
    two = type(h)(2.0)
    sixth = h / type(h)(6.0)
    # the slopes summed in the order of kernels/integrate.rk4_stage_fused (so the two round alike)
    dx = xv_start[1, 0, i] + xv_1[1, 0, i] * two + xv_2[1, 0, i] * two + xv_3[1, 0, i]
    dv = a_0[0, i] + a_1[0, i] * two + a_2[0, i] * two + a3
    xv_out[0, 0, i] = xv_start[0, 0, i] + dx * sixth
    xv_out[1, 0, i] = xv_start[1, 0, i] + dv * sixth


@wp.kernel(module=MODULE)
def semi_implicit_grad_kernel(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    step_in: wp.array(dtype=Any),  # (1,) internal step h, s
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (1,) mol
    # State in:
    xv_in: wp.array3d(dtype=Any),  # (2, 1, V) the step's first state
    fg_in: wp.array3d(dtype=Any),  # (2, 1, V) forces without pressure, dV/dx
    volume_in: wp.array2d(dtype=wp.float64),  # (1, 1) m^3
    # Out:
    xv_out: wp.array3d(dtype=Any),  # (2, 1, V) the state after the step
):
    """Semi-implicit Euler as kernels/integrate.integrate_semi_implicit_fused."""
    i = wp.tid()
    h = step_in[0]
    # (f + p dV/dx) (h / m): the order of kernels/integrate.integrate_semi_implicit_fused
    g = fg_in[1, 0, i]
    p = gauge_pressure(air_in[0], volume_in[0, 0], gas_rt, p_atm)
    v_new = xv_in[1, 0, i] + (fg_in[0, 0, i] + g * type(g[0])(p)) * (h * inv_mass[i])
    xv_out[1, 0, i] = v_new
    xv_out[0, 0, i] = xv_in[0, 0, i] + v_new * h


@wp.kernel(module=MODULE)
def jam_grad_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    jam_now: wp.array(dtype=wp.int32),  # (E,) 1 for the edges that jam at this event
    jam_stretch: Any,  # stretch stiffness multiplier
    jam_bend: Any,  # bending stiffness multiplier
    # State in:
    xv_in: wp.array3d(dtype=Any),  # (2, 1, V) the state the cells jam at
    edge_in: wp.array3d(dtype=Any),  # (4, 1, E) the edges before the event
    # Out:
    edge_out: wp.array3d(dtype=Any),  # (4, 1, E) after it
):
    """A jam event: the jamming edges freeze at their current length and angle and stiffen (as
    kernels/jamming.jam_edges_kernel); the other edges keep their values."""
    e = wp.tid()
    if jam_now[e] == 0:
        for r in range(4):
            edge_out[r, 0, e] = edge_in[r, 0, e]
        return
    h = hinges[e]
    x0 = xv_in[0, 0, h[0]]
    x1 = xv_in[0, 0, h[1]]
    edge_out[0, 0, e] = wp.length(x1 - x0)
    edge_out[1, 0, e] = dihedral_angle(x0, x1, xv_in[0, 0, h[2]], xv_in[0, 0, h[3]])
    edge_out[2, 0, e] = edge_in[2, 0, e] * jam_stretch
    edge_out[3, 0, e] = edge_in[3, 0, e] * jam_bend


@wp.kernel(enable_backward=False, module=MODULE)
def tape_store_kernel(
    # Control:
    slot_in: wp.array(dtype=wp.int32),  # (1,) the tape slot to write
    # State in:
    rows_in: wp.array3d(dtype=Any),  # (R, 1, V) one internal step's state in and intermediates
    volumes_in: wp.array3d(dtype=wp.float64),  # (S, 1, 1) its stages' volumes, m^3
    # Out:
    rows_out: wp.array3d(dtype=Any),  # (slots, >= R, V) the tape
    volumes_out: wp.array2d(dtype=wp.float64),  # (slots, S)
):
    """Keep one internal step's intermediates (rows_out's R rows) on the tape (launched over V)."""
    i = wp.tid()
    s = slot_in[0]
    for r in range(rows_out.shape[1]):
        rows_out[s, r, i] = rows_in[r, 0, i]
    if i == 0:
        for r in range(volumes_in.shape[0]):
            volumes_out[s, r] = volumes_in[r, 0, 0]


@wp.kernel(enable_backward=False, module=MODULE)
def tape_load_kernel(
    # Control:
    slot_in: wp.array(dtype=wp.int32),  # (1,) the tape slot to read
    # State in:
    rows_in: wp.array3d(dtype=Any),  # (slots, >= R, V) the tape
    volumes_in: wp.array2d(dtype=wp.float64),  # (slots, S)
    # Out:
    rows_out: wp.array3d(dtype=Any),  # (R, 1, V) the internal step's state in and intermediates
    volumes_out: wp.array3d(dtype=wp.float64),  # (S, 1, 1) m^3
):
    """Restore one internal step's intermediates (rows_in's R rows) from the tape (launched over V)."""
    i = wp.tid()
    s = slot_in[0]
    for r in range(rows_in.shape[1]):
        rows_out[r, 0, i] = rows_in[s, r, i]
    if i == 0:
        for r in range(volumes_out.shape[0]):
            volumes_out[r, 0, 0] = volumes_in[s, r]


@wp.kernel(enable_backward=False, module=MODULE)
def advance_slot_kernel(
    # Control:
    delta: int,  # +1 after a recorded step, -1 before an adjoint step
    # Out:
    slot_out: wp.array(dtype=wp.int32),  # (1,) the tape slot, updated
):
    """Move the tape's slot index (inside the captured graphs, so they serve every slot)."""
    slot_out[0] = slot_out[0] + delta


@wp.func
def acceleration_adjoint(a_bar: Any, fg: wp.array3d(dtype=Any), volume: wp.array2d(dtype=wp.float64),
                         air: wp.array(dtype=wp.float64), gas_rt: wp.float64, p_atm: wp.float64, inv_mass: Any, i: int,
                         fg_adj: wp.array3d(dtype=Any), volume_adj: wp.array2d(dtype=wp.float64),
                         air_adj: wp.array(dtype=wp.float64), inv_mass_adj: wp.array(dtype=Any)):
    """The adjoint of ``acceleration`` (vertex i) with a_bar the adjoint of its result: accumulated into
    the forces' and dV/dx's adjoints (vertex i), the inverse mass's (i), the volume's and the air's."""
    f = fg[0, 0, i]
    g = fg[1, 0, i]
    p = gauge_pressure(air[0], volume[0, 0], gas_rt, p_atm)
    pp = type(inv_mass)(p)
    fg_adj[0, 0, i] = fg_adj[0, 0, i] + a_bar * inv_mass
    fg_adj[1, 0, i] = fg_adj[1, 0, i] + a_bar * (inv_mass * pp)
    inv_mass_adj[i] = inv_mass_adj[i] + wp.dot(a_bar, f + g * pp)
    p_bar = wp.float64(wp.dot(a_bar, g) * inv_mass)
    vol = volume[0, 0]
    wp.atomic_add(air_adj, 0, p_bar * gas_rt / vol)
    wp.atomic_add(volume_adj, 0, 0, -p_bar * air[0] * gas_rt / (vol * vol))


@wp.kernel(enable_backward=False, module=MODULE)
def rk4_point_adjoint_kernel(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    step_in: wp.array(dtype=Any),  # (1,) internal step h, s
    fraction: Any,  # the next stage point's share of h
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (1,) mol
    # State in (the forward's inputs):
    fg_in: wp.array3d(dtype=Any),  # (2, 1, V) this stage's forces without pressure, dV/dx
    volume_in: wp.array2d(dtype=wp.float64),  # (1, 1) this stage's volume, m^3
    # State in (adjoints of the forward's outputs):
    accel_adj: wp.array2d(dtype=Any),  # (1, V)
    xv_next_adj: wp.array3d(dtype=Any),  # (2, 1, V)
    # Out (accumulated):
    inv_mass_adj: wp.array(dtype=Any),
    air_adj: wp.array(dtype=wp.float64),
    xv_start_adj: wp.array3d(dtype=Any),  # (2, 1, V); may be xv_stage_adj (the first stage)
    xv_stage_adj: wp.array3d(dtype=Any),
    fg_adj: wp.array3d(dtype=Any),
    volume_adj: wp.array2d(dtype=wp.float64),
):
    """The vector-Jacobian product of ``rk4_point_kernel`` (Warp's generated adjoint replays the
    forward and cost 10x the kernel): the adjoints of its inputs from those of its outputs."""
    i = wp.tid()
    c = fraction * step_in[0]
    nx_bar = xv_next_adj[0, 0, i]
    nv_bar = xv_next_adj[1, 0, i]
    xv_start_adj[0, 0, i] = xv_start_adj[0, 0, i] + nx_bar
    xv_start_adj[1, 0, i] = xv_start_adj[1, 0, i] + nv_bar
    xv_stage_adj[1, 0, i] = xv_stage_adj[1, 0, i] + nx_bar * c
    acceleration_adjoint(accel_adj[0, i] + nv_bar * c, fg_in, volume_in, air_in, gas_rt, p_atm, inv_mass[i], i,
                         fg_adj, volume_adj, air_adj, inv_mass_adj)


@wp.kernel(enable_backward=False, module=MODULE)
def rk4_combine_adjoint_kernel(
    # Model:
    inv_mass: wp.array(dtype=Any),  # (V,) 1/kg
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    step_in: wp.array(dtype=Any),  # (1,) internal step h, s
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (1,) mol
    # State in (the forward's inputs):
    fg_3: wp.array3d(dtype=Any),  # (2, 1, V) the last stage's forces without pressure, dV/dx
    volume_3: wp.array2d(dtype=wp.float64),  # (1, 1) m^3
    # State in (adjoint of the forward's output):
    xv_out_adj: wp.array3d(dtype=Any),  # (2, 1, V)
    # Out (accumulated):
    inv_mass_adj: wp.array(dtype=Any),
    air_adj: wp.array(dtype=wp.float64),
    xv_start_adj: wp.array3d(dtype=Any),  # (2, 1, V)
    xv_1_adj: wp.array3d(dtype=Any),
    xv_2_adj: wp.array3d(dtype=Any),
    xv_3_adj: wp.array3d(dtype=Any),
    a_0_adj: wp.array2d(dtype=Any),  # (1, V)
    a_1_adj: wp.array2d(dtype=Any),
    a_2_adj: wp.array2d(dtype=Any),
    fg_3_adj: wp.array3d(dtype=Any),
    volume_3_adj: wp.array2d(dtype=wp.float64),
):
    """The vector-Jacobian product of ``rk4_combine_kernel`` (written by hand, as the stage points')."""
    i = wp.tid()
    sixth = step_in[0] / type(step_in[0])(6.0)
    two_sixth = sixth * type(sixth)(2.0)
    ox_bar = xv_out_adj[0, 0, i]
    ov_bar = xv_out_adj[1, 0, i]
    xv_start_adj[0, 0, i] = xv_start_adj[0, 0, i] + ox_bar
    xv_start_adj[1, 0, i] = xv_start_adj[1, 0, i] + ov_bar + ox_bar * sixth
    xv_1_adj[1, 0, i] = xv_1_adj[1, 0, i] + ox_bar * two_sixth
    xv_2_adj[1, 0, i] = xv_2_adj[1, 0, i] + ox_bar * two_sixth
    xv_3_adj[1, 0, i] = xv_3_adj[1, 0, i] + ox_bar * sixth
    a_0_adj[0, i] = a_0_adj[0, i] + ov_bar * sixth
    a_1_adj[0, i] = a_1_adj[0, i] + ov_bar * two_sixth
    a_2_adj[0, i] = a_2_adj[0, i] + ov_bar * two_sixth
    acceleration_adjoint(ov_bar * sixth, fg_3, volume_3, air_in, gas_rt, p_atm, inv_mass[i], i, fg_3_adj,
                         volume_3_adj, air_adj, inv_mass_adj)
