"""Contact with rigid frictionless indenters and the held plug (warp_shape/physics/contact.py): their
forces are minus the gradients of their energies (float64 central differences; a sphere's on the faces,
at their closest points at a vertex, on an edge and inside a face), their kernels' adjoints match central
differences, the settle presses a membrane to a depth, and a held membrane keeps its plug where it was."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import warp_shape as ws
from energy_check import assert_force_is_minus_energy_gradient
from warp_shape.physics.contact import add_hold, add_indenter


@wp.kernel
def dot_kernel(f: wp.array2d(dtype=wp.vec3d), r: wp.array2d(dtype=wp.vec3d), loss: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(loss, 0, wp.dot(f[0, i], r[0, i]))


def contact_design():
    design = ws.Design(ws.icosphere(1, 0.04))
    x = design.rest.vertices
    top, bottom = int(np.argmax(x[:, 2])), int(np.argmin(x[:, 2]))
    add_indenter(design, "sphere", (0, 0, 1), x[top] + [0.0, 0.0, 0.008], 0.008, stiffness=1e4)
    add_indenter(design, "plate", (0, 0, -1), x[bottom], stiffness=1e4)
    add_hold(design, [bottom], [x[bottom] + [0.001, 0.0, 0.0]], stiffness=500.0)
    # two more spheres over a face's centroid and an edge's midpoint: the faces' closest points inside a
    # face and on an edge (the top's are the top vertex)
    faces, edges = design.rest.faces, design.rest.edges
    f = int(np.argmax(x[faces].mean(axis=1)[:, 0]))  # the face furthest along +x
    e = int(np.argmax(x[edges].mean(axis=1)[:, 1]))  # the edge furthest along +y
    for p in (x[faces[f]].mean(axis=0), x[edges[e]].mean(axis=0)):
        n = p / np.linalg.norm(p)
        add_indenter(design, "sphere", n, p + 0.008 * n, 0.008, stiffness=1e4)
    return design, top, bottom


@pytest.mark.parametrize("family", ["indenter", "hold"])
def test_contact_forces_are_minus_the_gradients_of_their_energies(family):
    design, top, bottom = contact_design()
    sim = ws.Simulator(design, precision="float64")
    sim.set_actuator_controls("indenter", [0.002, 0.001, 0.002, 0.002])  # the spheres 2 mm in, the plate 1 mm
    rng = np.random.default_rng(3)
    x0 = design.rest.vertices + 2e-4 * rng.standard_normal(design.rest.vertices.shape)
    sim.positions = x0
    force = sim.forces(family)
    touched = np.flatnonzero(np.abs(force).sum(axis=1))
    # both indenters push (their vertices), the hold pulls its vertex
    assert set(touched.tolist()) >= ({top, bottom} if family == "indenter" else {bottom})
    if family == "indenter":  # the spheres over a face and an edge push on its three and its two vertices
        assert len(touched) == 2 + 3 + 2
    assert sim.energy()[family] > 0
    assert_force_is_minus_energy_gradient(sim, family, x0, touched, abs_tol=1e-7)
    if family == "indenter":  # the sphere pushes its vertex down, the plate its vertex up
        assert force[top, 2] < -10.0 and force[bottom, 2] > 5.0
        sim.positions = x0
        sim.set_actuator_mask("indenter", [False] * 4)  # masked out: no force, no energy
        assert np.all(sim.forces("indenter") == 0) and sim.energy()["indenter"] == 0


def test_a_settle_presses_the_membrane_to_the_indenters_depth_and_holds_the_plug():
    design = ws.Design(ws.icosphere(2, 0.04))
    x = design.rest.vertices
    top = int(np.argmax(x[:, 2]))
    plug = np.flatnonzero(x[:, 2] < -0.035)
    add_indenter(design, "plate", (0, 0, 1), x[top])
    add_hold(design, plug, x[plug], stiffness=1e5)
    sim = ws.Simulator(design, precision="float64")
    sim.air_moles *= 1.3
    sim.settle_static()
    free_top = sim.positions[top, 2]
    sim.set_actuator_controls("indenter", [x[top, 2] - free_top + 0.005])  # 5 mm below the inflated top
    out = sim.settle_static()
    assert out.converged.all()
    xs = sim.positions
    assert xs[:, 2].max() == pytest.approx(free_top - 0.005, abs=2e-6)  # flattened at the plate (penalty)
    assert np.abs(xs[plug] - x[plug]).max() < 1e-4  # the plug stayed (its springs: 1e5 N/m)
    assert sim.forces("indenter")[:, 2].sum() < -0.1  # the plate carries the load
    assert sim.forces("hold")[:, 2].sum() == pytest.approx(-sim.forces("indenter")[:, 2].sum(), rel=1e-3)


def test_the_contact_kernels_adjoints_match_central_differences():
    """The indenter's and the hold's force kernels run backward (Warp's adjoint): d (f . r) / dx from the
    tape against float64 central differences of f . r (a Hessian-vector product of the penalty)."""
    from warp_shape.kernels import contact as kc

    design, top, bottom = contact_design()
    sim = ws.Simulator(design, precision="float64")
    sim.set_actuator_controls("indenter", [0.002, 0.001, 0.002, 0.002])
    dev, host = sim.model.actuators, sim.model.host.actuators
    rng = np.random.default_rng(5)
    x0 = design.rest.vertices + 2e-4 * rng.standard_normal(design.rest.vertices.shape)
    r = rng.standard_normal(x0.shape)

    def f_dot_r(x_np, grad=False):
        x = wp.array(x_np[None], dtype=wp.vec3d, requires_grad=grad)
        f = wp.zeros_like(x)
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=grad)
        rr = wp.array(r[None], dtype=wp.vec3d)
        tape = wp.Tape()
        with tape:
            ind = dev["indenter"]
            args = [ind["kind"], ind["axis"], ind["origin"], ind["radius"], ind["stiffness"], 0,
                    sim.control.values["indenter"], sim.control.enabled["indenter"], x, f]
            wp.launch(kc.indenter_force_kernel, (1, len(x0)), args)  # the plate, on vertices
            wp.launch(kc.indenter_face_force_kernel, (1, len(ind["faces"])), [ind["faces"], *args])  # the sphere
            hold = dev["hold"]
            wp.launch(kc.hold_force_kernel, (1, len(host["hold"]["vertex"])),
                      [hold["vertex"], hold["point"], hold["stiffness"], x, f])
            wp.launch(dot_kernel, len(x0), [f, rr, loss])
        if not grad:
            return float(loss.numpy()[0])
        tape.backward(loss)
        return x.grad.numpy()[0]

    g = f_dot_r(x0, grad=True)
    assert np.abs(g[top]).max() > 1.0 and np.abs(g[bottom]).max() > 1.0
    pressed = np.flatnonzero(np.abs(sim.forces("indenter")).sum(axis=1))  # the vertices of the face and edge too
    assert len(pressed) == 7
    h = 1e-8
    for v in pressed:
        for c in range(3):
            xp, xm = x0.copy(), x0.copy()
            xp[v, c] += h
            xm[v, c] -= h
            assert g[v, c] == pytest.approx((f_dot_r(xp) - f_dot_r(xm)) / (2 * h), rel=1e-5, abs=1e-4)



def test_a_fingertip_pressed_into_the_membrane_steps_stably_in_time():
    """The stable step counts the contact penalty: its rows are outside the elastic operator that the
    Lanczos bound measures, so they are added to that bound (Weyl), not capped by it. Without them the
    step is the free membrane's and the pressed membrane blows up within a few output steps."""
    design = ws.Design(ws.icosphere(2, 0.04))
    x = design.rest.vertices
    top = int(np.argmax(x[:, 2]))
    plug = np.flatnonzero(x[:, 2] < -0.035)
    add_indenter(design, "sphere", (0, 0, 1), x[top] + [0.0, 0.0, 0.008], 0.008)  # default penalty 2e5 N/m
    add_hold(design, plug, x[plug], stiffness=1e5)
    sim = ws.Simulator(design, precision="float64")
    sim.air_moles *= 1.3
    sim.settle_static()
    lift = sim.positions[top, 2] - x[top, 2]
    sim.set_actuator_controls("indenter", [lift + 0.003])  # 3 mm into the inflated top
    sim.step(40)
    assert np.isfinite(sim.positions).all()
    assert sim.positions[:, 2].max() < x[top, 2] + lift - 0.0025  # pressed, not thrown off
