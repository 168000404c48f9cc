"""The hand-written adjoints of the replay's RK4 kernels (gradients/step_adjoints.py) against Warp's
generated adjoints of the same kernels: for random inputs and random adjoints of the outputs, every
input's adjoint (accumulated onto a random start, as Warp's are) must agree to rounding (float64, the
gradients' precision: a float32 check would rebuild the adjoint module in the suite for float32 alone),
with the first stage's point being the step's start (one array, as the replay has it).
The outputs' own adjoints are not compared: Warp's adjoint zeroes them after reading, the replay
zeroes them before every step's adjoint."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warp_shape.gradients.differentiable_replay import adjoint_argument
from warp_shape.gradients.step_adjoints import adjoint_launch
from warp_shape.kernels import adjoint as ka

V = 37
PRECISION = {"float64": (wp.float64, wp.vec3d, np.float64, 1e-12), "float32": (wp.float32, wp.vec3f, np.float32, 2e-5)}


def _arrays(precision: str, seed: int):
    """(named inputs, the kernels' launches) for one random evaluation point, every array with a random
    gradient (adjoints accumulate onto what is there)."""
    scalar, vec3, dt, _ = PRECISION[precision]
    rng = np.random.default_rng(seed)

    def arr(shape, dtype, scale=1.0, offset=0.0):
        n = shape + ((3,) if dtype in (wp.vec3d, wp.vec3f) else ())
        host = (offset + scale * rng.standard_normal(n)).astype(np.float64 if dtype is wp.float64 else dt)
        a = wp.array(host, dtype=dtype, requires_grad=True)
        a.grad.assign(rng.standard_normal(n).astype(host.dtype))
        return a

    a = dict(inv_mass=arr((V,), scalar, 0.1, 2.0), step=wp.array(np.array([2e-3], dt), dtype=scalar),
             air=arr((1,), wp.float64, 1e-4, 0.01), start=arr((2, 1, V), vec3), p1=arr((2, 1, V), vec3),
             p2=arr((2, 1, V), vec3), p3=arr((2, 1, V), vec3), fg=arr((2, 1, V), vec3), fg3=arr((2, 1, V), vec3),
             vol=arr((1, 1), wp.float64, 1e-6, 2e-4), vol3=arr((1, 1), wp.float64, 1e-6, 2e-4),
             acc=[arr((1, V), vec3) for _ in range(3)], out=arr((2, 1, V), vec3))
    gas = (wp.float64(2436.0), wp.float64(101325.0))
    point0 = (ka.rk4_point_kernel, V, [a["inv_mass"], *gas, a["step"], scalar(0.5), a["air"], a["start"], a["start"],
                                        a["fg"], a["vol"], a["acc"][0], a["p1"]])
    point1 = (ka.rk4_point_kernel, V, [a["inv_mass"], *gas, a["step"], scalar(1.0), a["air"], a["start"], a["p2"],
                                        a["fg"], a["vol"], a["acc"][1], a["p3"]])
    combine = (ka.rk4_combine_kernel, V, [a["inv_mass"], *gas, a["step"], a["air"], a["start"], a["p1"], a["p2"],
                                          a["p3"], *a["acc"], a["fg3"], a["vol3"], a["out"]])
    return a, [point0, point1, combine]


OUTPUTS = ({"acc0", "p1"}, {"acc1", "p3"}, {"out"})  # each launch's outputs: Warp's adjoint zeroes their adjoints


def _grads(a, outputs) -> list:
    named = {k: v for k, v in a.items() if k != "acc"} | {f"acc{j}": x for j, x in enumerate(a["acc"])}
    return [x.grad.numpy().astype(np.float64) for k, x in named.items() if k not in outputs and x.grad is not None]


@pytest.mark.parametrize("precision", ["float64"])
@pytest.mark.parametrize("which", [0, 1, 2], ids=["first_stage_point", "stage_point", "combine"])
def test_the_hand_written_rk4_adjoint_is_warps(precision, which):
    tol = PRECISION[precision][3]
    generated, ours = _arrays(precision, 3), _arrays(precision, 3)
    kernel, dim, inputs = generated[1][which]
    wp.launch(kernel, dim, inputs, adj_inputs=[adjoint_argument(x) for x in inputs], adjoint=True)
    hand = adjoint_launch(*ours[1][which])
    assert hand is not None and hand[0] is not kernel
    wp.launch(*hand)
    changed = 0
    outputs = OUTPUTS[which]
    before = _grads(_arrays(precision, 3)[0], outputs)
    for g, o, b in zip(_grads(generated[0], outputs), _grads(ours[0], outputs), before):
        scale = max(np.abs(g).max(), 1e-30)
        assert np.abs(o - g).max() <= tol * scale, (np.abs(o - g).max(), scale)
        changed += int(np.abs(g - b).max() > tol * scale)
    assert changed >= 5  # the product reached the inputs (not a comparison of untouched gradients)


def test_kernels_without_a_hand_written_adjoint_keep_warps():
    assert adjoint_launch(ka.start_forces_kernel, 1, []) is None
