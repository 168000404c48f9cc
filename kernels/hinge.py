"""The fused per-hinge force pass of a step, composed from the springs, bending and pressure functions.

One pass over the hinges evaluates every force family but IPAMs and viscous damping (spring +
damper, bending when k_t > 0, and the pressure's volume gradient), launched 1-D over W * E so that
no thread pays for a 2-D index decomposition when there is one world. Pressure needs the enclosed
volume before it can be applied, so the pass accumulates the volume and dV/dx; the integrator stage
kernel then adds p dV/dx with p = n R T / V - p_atm. Each face appears in three hinges (once per
edge); the model gives it to one of them (Model.hinge_owns), which adds its whole contribution.
"""

from typing import Any

import warp as wp

from .bending import hinge_bending_forces
from .common import world_and_index
from .pressure import add_face_volume
from .springs import edge_frame, spring_stretch_force


def make_hinge_kernel(name: str, with_bending: bool, module: str | None = None):
    """The fused per-hinge kernel, specialised at compile time with or without bending (k_t = 0
    designs launch the kernel whose name carries no 'bending' and that holds no bending code).
    ``module`` given: a backward-enabled build in that Warp module, so the step's own module keeps
    its forward-only build."""

    def kernel(
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
        inv_len, len_e, dhat = edge_frame(edge)
        fs = spring_stretch_force(dhat, len_e, edge_in[0, w, e], edge_in[2, w, e], damping,
                                  xv_in[1, w, h[1]] - xv_in[1, w, h[0]])
        f0 = fs
        f1 = -fs
        if wp.static(with_bending):
            fb0, fb1, f2, f3 = hinge_bending_forces(edge, wing_a, wing_b, n_a, n_b, inv_len, len_e,
                                                    edge_in[3, w, e], edge_in[1, w, e], paper_variant)
            wp.atomic_add(fg_out, 0, w, h[0], f0 + fb0)
            wp.atomic_add(fg_out, 0, w, h[1], f1 + fb1)
            wp.atomic_add(fg_out, 0, w, h[2], f2)
            wp.atomic_add(fg_out, 0, w, h[3], f3)
        else:
            wp.atomic_add(fg_out, 0, w, h[0], f0)
            wp.atomic_add(fg_out, 0, w, h[1], f1)
        # pressure: each face's volume and dV/dx, added by the one hinge that owns the face
        own = owns[e]
        if own & 1:
            add_face_volume(n_a, x0, h[0], h[1], h[2], w, vslot, fg_out, volume_out)
        if own & 2:
            add_face_volume(n_b, x1, h[0], h[1], h[3], w, vslot, fg_out, volume_out)

    kernel.__name__ = kernel.__qualname__ = name
    if module is None:
        return wp.kernel(kernel, enable_backward=False)
    return wp.kernel(kernel, enable_backward=True, module=module)


#: fused pass without bending (k_t = 0): spring + damper, volume and dV/dx
eval_hinge_kernel = make_hinge_kernel("eval_hinge_kernel", False)
#: fused pass: spring + damper, hinge bending, volume and dV/dx
eval_hinge_bending_kernel = make_hinge_kernel("eval_hinge_bending_kernel", True)
