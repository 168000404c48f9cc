"""The hand-written adjoint of the fused hinge pass against central finite differences (float64).

The replay's pass is the step's (hinge.make_hinge_kernel): the same forces, volume and dV/dx, bit for
bit, checked here too.

``kernels/adjoint.hinge_adjoint_kernel`` is the vector-Jacobian product of the pass the differentiable
replay runs (``hinge_grad_kernel``: spring + damper, bending, the faces' volume and dV/dx). For random
adjoints of its outputs (forces, dV/dx, volume) on a perturbed, moving 42-vertex icosphere, the product
with random directions of its inputs (positions, velocities, the four edge fields) must equal the
central difference of the outputs' weighted sum, each output family alone, for both bending variants.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import warp_shape as ws
from warp_shape.kernels import adjoint as ka
from warp_shape.kernels.hinge import eval_hinge_bending_kernel
from warp_shape.model import host_model

DAMPING = 0.05


class Pass:
    """The hinge pass on an icosphere(1) membrane: forward outputs and the adjoint of its inputs."""

    def __init__(self, paper_variant: int, outputs: str = "all", seed: int = 0):
        rng = np.random.default_rng(seed)
        h = host_model(ws.Design(ws.icosphere(1, 0.04), ws.Material(bending_stiffness=2e-4)))
        self.V, self.E, self.paper = len(h.rest_vertices), len(h.hinges), paper_variant
        self.hinges = wp.array(h.hinges.astype(np.int32), dtype=wp.vec4i)
        self.owns = wp.array(h.hinge_owns, dtype=wp.int32)
        x = h.rest_vertices * (1.0 + 0.05 * rng.standard_normal((self.V, 1)))
        self.xv = np.stack([x, 0.05 * rng.standard_normal((self.V, 3))])
        self.edge = np.stack([np.full(self.E, 0.012) * (1 + 0.1 * rng.standard_normal(self.E)),
                              0.3 * rng.standard_normal(self.E), np.full(self.E, 40.0) * (1 + 0.2 * rng.random(self.E)),
                              np.full(self.E, 2e-4) * (1 + rng.random(self.E))])
        # the adjoints of one output family (or all): forces (per N), dV/dx (per m^2), volume (per m^3)
        self.fg_bar = rng.standard_normal((2, self.V, 3))
        self.vol_bar = float(rng.standard_normal()) if outputs in ("volume", "all") else 0.0
        for row, family in enumerate(("forces", "dV/dx")):
            if outputs not in (family, "all"):
                self.fg_bar[row] = 0.0

    def _inputs(self, xv, edge):
        fg = wp.zeros((2, 1, self.V), dtype=wp.vec3d, requires_grad=True)
        vol = wp.zeros((1, 1), dtype=wp.float64, requires_grad=True)
        angles = wp.zeros((2, 1, self.E), dtype=wp.float64)  # a tape of two slots, the second one used
        return [self.hinges, self.owns, wp.float64(DAMPING), self.paper, 1, self.E,
                wp.array(edge.reshape(4, 1, -1), dtype=wp.float64, requires_grad=True),
                wp.array(xv.reshape(2, 1, -1, 3), dtype=wp.vec3d, requires_grad=True), 0, fg, vol, angles,
                wp.array([1], dtype=wp.int32), 0]

    def weighted(self, xv, edge) -> float:
        """sum of the outputs weighted by their adjoints."""
        inputs = self._inputs(xv, edge)
        wp.launch(ka.hinge_grad_kernel, self.E, inputs)
        fg, vol = inputs[9].numpy()[:, 0], float(inputs[10].numpy()[0, 0])
        return float(np.sum(fg * self.fg_bar)) + vol * self.vol_bar

    def adjoint(self):
        """(d/d xv (2, V, 3), d/d edge (4, E)) of ``weighted`` from the hand-written kernel (after the
        forward pass, which leaves the hinges' angles on the tape)."""
        inputs = self._inputs(self.xv, self.edge)
        wp.launch(ka.hinge_grad_kernel, self.E, inputs)
        fg, vol, edge, xv = inputs[9], inputs[10], inputs[6], inputs[7]
        fg.grad.assign(self.fg_bar.reshape(2, 1, -1, 3))
        vol.grad.assign(np.array([[self.vol_bar]]))
        wp.launch(ka.hinge_adjoint_kernel, self.E, [*inputs[:9], fg.grad, vol.grad, edge.grad, xv.grad, *inputs[11:]])
        return xv.grad.numpy()[:, 0], edge.grad.numpy()[:, 0]


@pytest.mark.parametrize("paper_variant, outputs", [(0, "forces"), (0, "dV/dx"), (0, "volume"), (1, "all")])
def test_hinge_adjoint_matches_central_differences(paper_variant, outputs):
    p = Pass(paper_variant, outputs)
    xv_bar, edge_bar = p.adjoint()
    rng = np.random.default_rng(1)
    # directions: positions, velocities and each edge field alone, then all at once
    scales = [("x", 1e-3), ("v", 1e-1), ("rest length", 1e-3), ("rest angle", 1e-1), ("stretch", 1.0),
              ("bending", 1e-4), ("all", None)]
    for name, scale in scales:
        dxv, dedge = np.zeros_like(p.xv), np.zeros_like(p.edge)
        if name in ("x", "all"):
            dxv[0] = 1e-3 * rng.standard_normal(dxv[0].shape)
        if name in ("v", "all"):
            dxv[1] = 1e-1 * rng.standard_normal(dxv[1].shape)
        for r, field in enumerate(("rest length", "rest angle", "stretch", "bending")):
            if name in (field, "all"):
                dedge[r] = (scale or [1e-3, 1e-1, 1.0, 1e-4][r]) * rng.standard_normal(p.E)
        eps = 1e-4
        fd = (p.weighted(p.xv + eps * dxv, p.edge + eps * dedge)
              - p.weighted(p.xv - eps * dxv, p.edge - eps * dedge)) / (2 * eps)
        adj = float(np.sum(xv_bar * dxv) + np.sum(edge_bar * dedge))
        if outputs in ("dV/dx", "volume") and name in ("v", "rest length", "rest angle", "stretch", "bending"):
            assert adj == 0.0 and abs(fd) < 1e-12, f"{outputs} does not depend on the {name}"
            continue
        assert abs(adj - fd) <= 1e-7 * abs(fd), f"{name}: adjoint {adj:.12e}, central difference {fd:.12e}"


def test_the_replays_hinge_pass_is_the_steps():
    """kernels/adjoint.hinge_grad_kernel (which also keeps the angles) gives the step's fused pass's
    outputs bit for bit."""
    for paper in (0, 1):
        p = Pass(paper)
        ours = p._inputs(p.xv, p.edge)
        step = p._inputs(p.xv, p.edge)[:11]
        wp.launch(ka.hinge_grad_kernel, p.E, ours)
        wp.launch(eval_hinge_bending_kernel, p.E, step)
        assert np.array_equal(ours[9].numpy(), step[9].numpy()) and np.array_equal(ours[10].numpy(), step[10].numpy())
        assert np.abs(ours[11].numpy()[1]).max() > 0.05  # the angles are on the tape's slot 1


def test_every_input_receives_an_adjoint():
    """No family of inputs is left out: every vertex's position and every edge field gets a nonzero adjoint."""
    xv_bar, edge_bar = Pass(0).adjoint()
    assert np.all(np.linalg.norm(xv_bar[0], axis=1) > 0) and np.all(np.linalg.norm(xv_bar[1], axis=1) > 0)
    assert np.all(np.abs(edge_bar) > 0)
