"""Hand-written adjoints of the differentiable replay's integrator kernels (docs/gradients.md).

Warp's generated adjoint of a kernel replays the kernel's forward inside it; for the RK4 stage
points and combination that made the adjoint cost about 10x the kernel (at 642 vertices 0.47 ms of a
3.5 ms adjoint step). ``kernels/adjoint.rk4_point_adjoint_kernel`` and ``rk4_combine_adjoint_kernel``
are their vector-Jacobian products written out; ``adjoint_launch`` maps a recorded forward launch to
its hand-written adjoint's launch (``None`` where Warp's generated one is used).
"""

from __future__ import annotations

from warp_shape.kernels import adjoint as ka

__all__ = ["adjoint_launch"]


def _rk4_point(dim: int, inputs: list) -> tuple:
    inv_mass, gas_rt, p_atm, step, fraction, air, xv_start, xv_stage, fg, volume, accel, xv_next = inputs
    return ka.rk4_point_adjoint_kernel, dim, [inv_mass, gas_rt, p_atm, step, fraction, air, fg, volume, accel.grad,
                                              xv_next.grad, inv_mass.grad, air.grad, xv_start.grad, xv_stage.grad,
                                              fg.grad, volume.grad]


def _rk4_combine(dim: int, inputs: list) -> tuple:
    inv_mass, gas_rt, p_atm, step, air, xv_start, xv_1, xv_2, xv_3, a_0, a_1, a_2, fg_3, volume_3, xv_out = inputs
    return ka.rk4_combine_adjoint_kernel, dim, [inv_mass, gas_rt, p_atm, step, air, fg_3, volume_3, xv_out.grad,
                                                inv_mass.grad, air.grad, xv_start.grad, xv_1.grad, xv_2.grad,
                                                xv_3.grad, a_0.grad, a_1.grad, a_2.grad, fg_3.grad, volume_3.grad]


_HAND = {ka.rk4_point_kernel: _rk4_point, ka.rk4_combine_kernel: _rk4_combine}


def adjoint_launch(kernel, dim: int, inputs: list) -> tuple | None:
    """(kernel, dim, inputs) of the hand-written adjoint of a recorded launch of ``kernel``, or None
    where its adjoint is Warp's generated one. Every array the adjoint accumulates into must have
    its gradient (the replay's arrays do)."""
    make = _HAND.get(kernel)
    if make is None:
        return None
    return make(dim, inputs)
