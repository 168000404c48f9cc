"""Kernels shared by every force family: thread indexing, starting a force evaluation, edge read-outs,
world copies between batches.

Every kernel is generic over the precision: positions/velocities are ``wp.vec3f`` or ``wp.vec3d``
and every scalar follows them. Worlds share one Model: State/Control arrays carry a leading world
dimension W. Forces are scattered with ``atomic_add`` (a plain add on CPU, so CPU runs are
bit-for-bit deterministic).
"""

from typing import Any

import warp as wp

from .bending import dihedral_angle


@wp.func
def world_and_index(t: int, n: int, n_worlds: int):
    """(world, element) of a 1-D thread index over n_worlds * n elements."""
    if n_worlds == 1:
        return 0, t
    w = t // n
    return w, t - w * n


@wp.kernel(enable_backward=False)
def init_forces_viscous(
    # Model:
    viscous_damping: Any,  # c_v, N s/m (0 leaves the viscous term out)
    # State in:
    v_in: wp.array2d(dtype=Any),  # (W, V) m/s
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) N, overwritten with -c_v v
    volume_out: wp.array(dtype=wp.float64),  # (W,) m^3, zeroed for the volume pass
):
    """Start a per-family force evaluation: viscous damping initialises the force array."""
    w, i = wp.tid()
    f_out[w, i] = v_in[w, i] * (-viscous_damping)
    if i == 0:
        volume_out[w] = wp.float64(0.0)


@wp.kernel(enable_backward=False)
def init_step_forces(
    # Model:
    viscous_damping: Any,  # c_v, N s/m
    n_worlds: int,
    n_vertices: int,
    # State in:
    xv_in: wp.array3d(dtype=Any),  # (2, W, V) positions (m), velocities (m/s)
    # Out:
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) forces overwritten with -c_v v (N); dV/dx zeroed (m^2)
    volume_out: wp.array2d(dtype=wp.float64),  # (W, slots) m^3, zeroed
):
    """Start the first force evaluation of a step (later RK4 stages are started by the stage kernel)."""
    w, i = world_and_index(wp.tid(), n_vertices, n_worlds)
    v = xv_in[1, w, i]
    fg_out[0, w, i] = v * (-viscous_damping)
    fg_out[1, w, i] = v * type(viscous_damping)(0.0)
    if i == 0:
        for s in range(volume_out.shape[1]):
            volume_out[w, s] = wp.float64(0.0)


@wp.kernel(enable_backward=False)
def edge_state_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    length_out: wp.array2d(dtype=Any),  # (W, E) current edge lengths, m
    angle_out: wp.array2d(dtype=Any),  # (W, E) current dihedral angles, rad
):
    """Current edge lengths (m) and dihedral angles (rad), for jamming and read-outs."""
    w, e = wp.tid()
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    length_out[w, e] = wp.length(x1 - x0)
    angle_out[w, e] = dihedral_angle(x0, x1, x_in[w, h[2]], x_in[w, h[3]])


@wp.kernel(enable_backward=False)
def copy_worlds_kernel(
    # State in:
    src: wp.array3d(dtype=Any),  # (K, W_src, N) per-world rows of one array
    src_world: wp.array(dtype=wp.int32),  # (n,) the source world of each copy
    dst_world: wp.array(dtype=wp.int32),  # (n,) the destination world of each copy
    # Out:
    dst: wp.array3d(dtype=Any),  # (K, W_dst, N)
):
    """dst[k, dst_world[j], i] = src[k, src_world[j], i]: world copies between two batches."""
    j, k, i = wp.tid()
    dst[k, dst_world[j], i] = src[k, src_world[j], i]
