"""Hinge (dihedral) bending (SPEC section 4): the angle, its gradient, the wing forces and the kernel.

Hinge convention (``hinges[e] = (v0, v1, v2, v3)``): the edge runs v0 -> v1 in face A = (v0, v1, v2)
and v1 -> v0 in face B = (v1, v0, v3). The signed dihedral angle is 0 for a flat hinge and
positive where the outward-wound surface is convex.
"""

from typing import Any

import warp as wp

# atan(a) ~ a + a^3 P(a^2) on [0, 1]: a degree-7 minimax fit, |error| < 9e-8 rad in float32 arithmetic
# (float32 resolves 1.2e-7 rad at 1 rad). Inlined, it is 4x cheaper than a libm atan2f call, which
# also forces every live register of the hinge pass to be spilled around it.
ATAN_POLY = (-0.3333297921, 0.1999021044, -0.1418445101, 0.10567944, -0.07354022783, 0.04097336247,
             -0.01504203915, 0.0025998325)


@wp.func
def hinge_atan2(y: wp.float32, x: wp.float32):
    """atan2(y, x) in float32 through the inlined polynomial (octant reduction, then atan on [0, 1])."""
    ax = wp.abs(x)
    ay = wp.abs(y)
    a = wp.min(ax, ay) / wp.max(wp.max(ax, ay), wp.float32(1.0e-30))
    s = a * a
    p = wp.float32(wp.static(ATAN_POLY[7]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[6]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[5]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[4]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[3]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[2]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[1]))
    p = p * s + wp.float32(wp.static(ATAN_POLY[0]))
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
def hinge_angle(n_a: Any, n_b: Any, wing_b: Any, len_e: Any):
    """The dihedral angle from the two face normals (n_a = e x wing_a, n_b = wing_b x e, both twice
    the face area) and wing_b = x3 - x0: sine and cosine both scaled by |n_a| |n_b|, the sine through
    the dot product n_a . wing_b instead of a cross product."""
    return hinge_atan2(-wp.dot(n_a, wing_b) * len_e, wp.dot(n_a, n_b))


@wp.func
def wing_gradient(n: Any, len_e: Any):
    """d(theta)/d(wing vertex): -n_hat / h with h the wing's distance to the edge (n = 2 area n_hat)."""
    n2 = wp.dot(n, n)
    zero = type(len_e)(0.0)
    if n2 <= zero:
        return n * zero
    return n * (-len_e / n2)


@wp.func
def hinge_bending_forces(edge: Any, wing_a: Any, wing_b: Any, n_a: Any, n_b: Any, inv_len: Any, len_e: Any,
                         kt: Any, rest_angle: Any, paper_variant: int):
    """Bending forces (f0, f1, f2, f3) on the hinge vertices, energy 0.5 k_t (theta - theta_0)^2.

    Branch-free guards: a zero-area wing gets zero force through a floor on |n|^2. The wings take
    torque d(theta)/d(wing); the edge vertices take the lever-rule split of the wings' reactions
    (exact gradient) or, with ``paper_variant``, -(f2 + f3) / 2 each (paper eq. 9). f0 closes the sum,
    so the four forces sum to zero."""
    return bending_forces_at(hinge_angle(n_a, n_b, wing_b, len_e), edge, wing_a, wing_b, n_a, n_b, inv_len, len_e,
                             kt, rest_angle, paper_variant)


@wp.func
def bending_forces_at(theta: Any, edge: Any, wing_a: Any, wing_b: Any, n_a: Any, n_b: Any, inv_len: Any,
                      len_e: Any, kt: Any, rest_angle: Any, paper_variant: int):
    """``hinge_bending_forces`` at the hinge's angle theta (rad), given."""
    tiny = type(len_e)(1.0e-30)
    torque_l = kt * (theta - rest_angle) * len_e  # -torque |e|
    f2 = n_a * (torque_l / wp.max(wp.dot(n_a, n_a), tiny))
    f3 = n_b * (torque_l / wp.max(wp.dot(n_b, n_b), tiny))
    if paper_variant != 0:
        f1 = (f2 + f3) * type(len_e)(-0.5)
    else:
        # lever rule: each wing's reaction split by where it projects onto the edge
        il2 = inv_len * inv_len
        f1 = -(f2 * (wp.dot(wing_a, edge) * il2) + f3 * (wp.dot(wing_b, edge) * il2))
    return -(f2 + f3 + f1), f1, f2, f3


@wp.kernel(enable_backward=False)
def eval_bending_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    paper_variant: int,  # 0: exact gradient; 1: paper eq. (9) edge forces
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    rest_angle_in: wp.array2d(dtype=Any),  # (W, E) rad
    bend_in: wp.array2d(dtype=Any),  # (W, E) k_t, N m/rad, jam factor applied
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) N, accumulated
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
    kt = bend_in[w, e]
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
