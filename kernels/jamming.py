"""Particle jamming (SPEC section 4): freezing and stiffening the edges of a jammed cell."""

from typing import Any

import warp as wp

from .bending import dihedral_angle


@wp.kernel(enable_backward=False)
def jam_edges_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    cell_edges: wp.array(dtype=wp.int32),  # (n,) edges of the cell being jammed
    world_mask: wp.array(dtype=wp.int32),  # (W,) 1 for worlds that jam now
    jam_stretch: Any,  # stretch stiffness multiplier
    jam_bend: Any,  # bending stiffness multiplier
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    # Out (read and updated):
    edge_out: wp.array3d(dtype=Any),  # (4, W, E) rest length, rest angle, stretch and bending stiffness
    jammed_out: wp.array2d(dtype=wp.int32),  # (W, E) 1 where jammed
):
    """Freeze an edge at its current length and angle and stiffen it; an edge already jammed keeps
    its values (a jam is applied once)."""
    w, j = wp.tid()
    if world_mask[w] == 0:
        return
    e = cell_edges[j]
    if jammed_out[w, e] != 0:
        return
    h = hinges[e]
    x0 = x_in[w, h[0]]
    x1 = x_in[w, h[1]]
    edge_out[0, w, e] = wp.length(x1 - x0)
    edge_out[1, w, e] = dihedral_angle(x0, x1, x_in[w, h[2]], x_in[w, h[3]])
    edge_out[2, w, e] = edge_out[2, w, e] * jam_stretch
    edge_out[3, w, e] = edge_out[3, w, e] * jam_bend
    jammed_out[w, e] = 1
