"""Chamber pressure (SPEC section 4): enclosed volume, gauge pressure and the pressure force p dV/dx."""

from typing import Any

import warp as wp

from .common import world_and_index


@wp.func
def face_normal_area2(x0: Any, x1: Any, x2: Any):
    """Outward normal scaled by twice the face area."""
    return wp.cross(x1 - x0, x2 - x0)


@wp.func
def gauge_pressure(air: wp.float64, volume: wp.float64, gas_rt: wp.float64, p_atm: wp.float64):
    """Gauge pressure n R T / V - p_atm in Pa (air in mol, volume in m^3, gas_rt = R T in J/mol)."""
    return air * gas_rt / volume - p_atm


@wp.func
def add_face_volume(
    n: Any,  # the face's outward normal times twice its area, m^2
    x_face: Any,  # any vertex of the face, m
    a: int,  # the face's vertices
    b: int,
    c: int,
    w: int,  # world
    vslot: int,  # column of volume_out
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) row 1 += dV/dx, m^2
    volume_out: wp.array2d(dtype=wp.float64),  # (W, slots) += volume, m^3
):
    """Add one face's share of the enclosed volume (divergence theorem, x . n / 6) and its gradient
    n / 6 on each of its three vertices."""
    g = n * (type(x_face[0])(1.0) / type(x_face[0])(6.0))
    wp.atomic_add(volume_out, w, vslot, wp.float64(wp.dot(x_face, g)))
    wp.atomic_add(fg_out, 1, w, a, g)
    wp.atomic_add(fg_out, 1, w, b, g)
    wp.atomic_add(fg_out, 1, w, c, g)


@wp.kernel(enable_backward=False)
def eval_volume_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    volume_out: wp.array(dtype=wp.float64),  # (W,) m^3, accumulated; zero it first
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
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    volume_in: wp.array(dtype=wp.float64),  # (W,) m^3
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """Gauge pressure p = n R T / V - p_atm pushes each vertex of a face by p area / 3 n_hat."""
    w, f = wp.tid()
    tri = faces[f]
    x0 = x_in[w, tri[0]]
    n2a = face_normal_area2(x0, x_in[w, tri[1]], x_in[w, tri[2]])
    p = gauge_pressure(air_in[w], volume_in[w], gas_rt, p_atm)
    force = n2a * type(x0[0])(p / wp.float64(6.0))
    wp.atomic_add(f_out, w, tri[0], force)
    wp.atomic_add(f_out, w, tri[1], force)
    wp.atomic_add(f_out, w, tri[2], force)


@wp.kernel(enable_backward=False)
def finish_forces_kernel(
    # Model:
    gas_rt: wp.float64,  # R T, J/mol
    p_atm: wp.float64,  # Pa absolute
    n_worlds: int,
    n_vertices: int,
    # State in:
    volume_in: wp.array2d(dtype=wp.float64),  # (W, slots) m^3
    vslot: int,  # column of volume_in
    # Control:
    air_in: wp.array(dtype=wp.float64),  # (W,) mol
    # Out:
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) forces (N) += p dV/dx (row 1, m^2)
):
    """Add the pressure force p dV/dx of a fused evaluation (read-outs; steps do this in the stage kernel)."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    g = fg_out[1, w, i]
    p = gauge_pressure(air_in[w], volume_in[w, vslot], gas_rt, p_atm)
    fg_out[0, w, i] = fg_out[0, w, i] + g * type(g[0])(p)


@wp.kernel(enable_backward=False)
def pressure_rows_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,)
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    volume_out: wp.array(dtype=wp.float64),  # (W,) m^3, accumulated; zero it first
    perimeter_out: wp.array2d(dtype=wp.float64),  # (W, V) m, sum of perimeter / 6 of the vertex's faces, accumulated
    grad_out: wp.array2d(dtype=wp.vec3d),  # (W, V) dV/dx, m^2, accumulated
):
    """The stable step's chamber terms in float64 for every precision: the enclosed volume, each
    vertex's share of its faces' perimeters (the pressure's geometric stiffness per unit |p|) and dV/dx."""
    w, f = wp.tid()
    tri = faces[f]
    x0 = wp.vec3d(x_in[w, tri[0]])
    x1 = wp.vec3d(x_in[w, tri[1]])
    x2 = wp.vec3d(x_in[w, tri[2]])
    sixth = wp.float64(1.0) / wp.float64(6.0)
    wp.atomic_add(volume_out, w, wp.dot(x0, wp.cross(x1, x2)) * sixth)
    g = wp.cross(x1 - x0, x2 - x0) * sixth
    share = (wp.length(x1 - x0) + wp.length(x2 - x1) + wp.length(x0 - x2)) * sixth
    for k in range(3):
        wp.atomic_add(perimeter_out, w, tri[k], share)
        wp.atomic_add(grad_out, w, tri[k], g)
