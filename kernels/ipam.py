"""IPAM actuators (SPEC section 4, eqs. 3-5): the natural-length law and the sub-spring kernel."""

from typing import Any

import warp as wp

from .springs import spring_damper_force


@wp.func
def ipam_natural_length(free_length: Any, area_over_k: Any, pressure: Any):
    """Natural length L_n = L0 + (A/k) P in m at gauge pressure P (Pa)."""
    return free_length + area_over_k * pressure


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
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    v_in: wp.array2d(dtype=Any),  # (W, V) m/s
    # Control:
    pressure_in: wp.array2d(dtype=wp.float64),  # (W, n_ipam) gauge Pa
    enabled: wp.array2d(dtype=wp.int32),  # (W, n_ipam) 0 where the IPAM is masked out of the world
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """IPAM as three sub-springs of stiffness k/3 and natural length L_n + offset, L_n = L0 + (A/k) P.
    An IPAM masked out of a world (enabled 0) exerts no force there."""
    w, s = wp.tid()
    i = s // 3
    if enabled[w, i] == 0:
        return
    pair = sub_pairs[s]
    k = stiffness[i]
    natural = ipam_natural_length(free_length[i], area_over_k[i], type(k)(pressure_in[w, i])) + sub_offsets[s]
    f = spring_damper_force(x_in[w, pair[0]], x_in[w, pair[1]], v_in[w, pair[0]], v_in[w, pair[1]],
                            k / type(k)(3.0), natural, damping[i])
    wp.atomic_add(f_out, w, pair[0], f)
    wp.atomic_sub(f_out, w, pair[1], f)
