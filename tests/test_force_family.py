"""Force families registered from outside the package step, settle, read out and differentiate
through the same seam as the package's own.

A passive family (tests/anchor_family.py: springs from vertices to fixed points, their rest lengths
derived from the rest shape) and an actuator family (tests/toy_family.py: a tendon whose rest length
is its control) are registered by the tests; no package file names either. Each steps, settles
statically, appears in ``sim.forces(name)`` and ``sim.energy()[name]`` with its force the negative
gradient of its energy, and ``ws.gradient`` differentiates a replayed sequence through it: the rest
positions, its own parameters and (the tendon) its controls per row, against central differences
(float64, rtol 1e-4). The replay's forward composes the families as the simulator does: its final
shape is the simulator's, and its objective the control result's.
"""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from anchor_family import ANCHOR, AnchorFamily, add_anchor
from energy_check import assert_force_is_minus_energy_gradient
from generated_shapes import shape
from toy_family import TENDON, add_tendon
from warp_shape.errors import DesignError
from warp_shape.gradients import DifferentiableReplay
from warp_shape.objectives.radial import fit_objective_and_gradient
from warp_shape.simulation_settings import SimulationSettings

RTOL = 1e-4


@pytest.fixture(scope="module", autouse=True)
def families():
    """Both toy families registered for this module (and removed after)."""
    ws.FORCE_FAMILIES.register(ANCHOR, replace=True)
    ws.ACTUATOR_FAMILIES.register(TENDON, replace=True)
    yield
    ws.FORCE_FAMILIES.unregister(ANCHOR.name)
    ws.ACTUATOR_FAMILIES.unregister(TENDON.name)


def far_vertex(mesh, v: int) -> int:
    """The vertex about a quarter turn around the sphere from vertex v."""
    u = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return int(np.argmin(np.abs(u @ u[v])))


def anchored_design():
    """A 162-vertex sphere with one IPAM, its top vertex held by a spring to a point 8 mm above it
    (stretched from the start: slack 0.5) and a side vertex to a point 5 mm out (slack 1)."""
    d = ws.Design(ws.icosphere(2, 0.04))
    x = d.rest.vertices
    top, side = int(np.argmax(x[:, 2])), int(np.argmax(x[:, 0]))
    add_anchor(d, top, x[top] + [0, 0, 0.008], stiffness=40.0, slack=0.5)
    add_anchor(d, side, x[side] + [0.005, 0, 0], stiffness=25.0)
    c = d.rest.face_centroids()
    d.add_ipam(0, int(np.argmin(c @ c[0])))
    return d, (top, side)


def tendon_design():
    """A 162-vertex sphere with one IPAM and one tendon a quarter turn long."""
    d = ws.Design(ws.icosphere(2, 0.04))
    add_tendon(d, 0, far_vertex(d.rest, 0), stiffness=30.0)
    c = d.rest.face_centroids()
    d.add_ipam(0, int(np.argmin(c @ c[0])))
    return d


def control64(design, target):
    settings = ws.ControlSettings(method="paper", max_steps=12, max_settle_steps=6,
                                  simulation=SimulationSettings(precision="float64"))
    return ws.control(design, target, settings=settings)


def test_a_passive_family_from_outside_steps_settles_and_reads_out():
    d, (top, side) = anchored_design()
    sim = ws.Simulator(d, precision="float64")
    assert [f.name for f in sim.model.families] == ["ipam", "anchor"]
    assert "anchor_force_kernel" in " ".join(sim.step_kernels)
    rng = np.random.default_rng(3)
    x0 = d.rest.vertices + 2e-4 * rng.standard_normal(d.rest.vertices.shape)
    sim.positions = x0
    force = sim.forces("anchor")
    assert np.count_nonzero(np.abs(force).sum(1)) == 2 and np.abs(force[top]).max() > 0.1
    assert_force_is_minus_energy_gradient(sim, "anchor", x0, (top, side))
    assert sim.energy()["total"] == pytest.approx(sum(v for k, v in sim.energy().items() if k != "total"))
    with pytest.raises(DesignError, match="passive"):
        sim.set_actuator_controls("anchor", [0.0])
    # the stretched spring pulls the top out, and the whole membrane towards its anchors (the settle keeps
    # rigid motions, which the family's forces resist); the dynamics stays where the static settle ends
    sim.positions = d.rest.vertices
    sim.step(100)
    sim.settle_static()
    settled = sim.positions
    assert settled[top, 2] - d.rest.vertices[top, 2] > 1e-3
    assert np.abs(sim.forces()).max() < 1e-6
    sim.step(200)
    assert np.abs(sim.positions - settled).max() < 1e-6  # a micrometre: the settle found the rest state


def test_a_family_without_an_adjoint_is_refused_by_name_before_any_work():
    class Rigid(AnchorFamily):
        name, differentiable = "rigid_anchor", False
    fam = ws.FORCE_FAMILIES.register(Rigid())
    try:
        d, _ = anchored_design()
        d.add_element("rigid_anchor", d.elements("anchor")[0])
        res = control64(d, ws.target("oval"))
        with pytest.raises(DesignError, match="rigid_anchor.*no adjoint"):
            ws.gradient(d, res, wrt=("rest_positions",))
    finally:
        ws.FORCE_FAMILIES.unregister(fam.name)


class Case:
    """A float64 control result of ``design`` to ``target``, its replay and the adjoint's gradient."""

    def __init__(self, design, target):
        self.design, self.target = design, target.centered()
        self.result = control64(design, self.target)
        self.replay = DifferentiableReplay(design, self.result, precision="float64")
        self.plan = self.replay.forward()
        self.sampler = ws.RadialSampler(self.target)
        j, dj = self.objective(self.plan.final)
        self.j = j
        self.values = self.replay.backward(dj, j).values

    def objective(self, x):
        return fit_objective_and_gradient(x, self.sampler, 0, self.design.rest.faces, self.target.volume())

    def central(self, eps: float, **change) -> float:
        (key, fn), = change.items()
        pos = lambda e: (self.replay.positions(families={key: fn(e)}) if key not in ("rest",)  # noqa: E731
                         else self.replay.positions(rest=fn(e)))
        return (self.objective(pos(eps))[0] - self.objective(pos(-eps))[0]) / (2.0 * eps)


def close(adjoint: float, fd: float, scale: float) -> bool:
    return abs(adjoint - fd) <= RTOL * max(abs(fd), 1e-3 * scale)


def check_rest_gradient(case, vertices):
    g, x0 = case.values["rest_positions"], case.design.rest.vertices
    for v in vertices:
        for c in range(3):
            def moved(e, v=v, c=c):
                x = x0.copy()
                x[v, c] += e
                return x
            fd = case.central(1e-7, rest=moved)
            assert close(g[v, c], fd, np.abs(g).max()), (v, c, g[v, c], fd)


def check_array_gradient(case, name, base, eps=1e-6):
    g = np.asarray(case.values[name]).reshape(-1)
    flat = np.asarray(base, dtype=np.float64).reshape(-1)
    for i in range(flat.size):
        def moved(e, i=i):
            b = flat.copy()
            b[i] += e * max(abs(flat[i]), 1e-3)
            return b.reshape(np.shape(base))
        fd = case.central(eps, **{name: moved}) / max(abs(flat[i]), 1e-3)
        assert close(g[i], fd, np.abs(g).max()), (name, i, g[i], fd)


@pytest.fixture(scope="module")
def anchor_case():
    d, ends = anchored_design()
    case = Case(d, ws.target("oval"))
    case.ends = ends
    return case


def test_the_replay_composes_the_anchor_family_as_the_simulator_does(anchor_case):
    c = anchor_case
    assert c.result.objective == c.j  # the replayed objective is the control result's, bit for bit
    np.testing.assert_allclose(c.replay.positions(), c.plan.final, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(c.plan.final, ws.replay(c.design, c.result))  # the simulator's replay


def test_anchor_gradients_match_central_differences(anchor_case):
    c = anchor_case
    top, side = c.ends
    assert set(ws.gradients.api.gradient_parameters(c.design)) >= {"anchor_stiffness", "anchor_point"}
    assert np.abs(c.values["anchor_stiffness"]).max() > 0 and np.abs(c.values["anchor_point"]).max() > 0
    check_array_gradient(c, "anchor_stiffness", [a.stiffness for a in c.design.elements("anchor")])
    check_array_gradient(c, "anchor_point", [a.point for a in c.design.elements("anchor")])
    check_rest_gradient(c, [top, side, far_vertex(c.design.rest, top)])


@pytest.fixture(scope="module")
def tendon_case():
    return Case(tendon_design(), shape("peanut", subdivisions=3))


def test_the_replay_with_a_tendon_is_the_simulators_and_its_objective_the_results(tendon_case):
    c = tendon_case
    assert c.plan.family_controls["tendon"].shape == (len(c.plan.air), 1)
    assert c.result.objective == c.j  # the replayed objective is the control result's, bit for bit
    np.testing.assert_allclose(c.replay.positions(), c.plan.final, rtol=0, atol=1e-12)
    g = ws.gradient(c.design, c.result, wrt=("rest_positions", "tendon_stiffness"))
    assert g.objective == c.result.objective


def test_tendon_gradients_match_central_differences(tendon_case):
    c = tendon_case
    a, b = c.design.elements("tendon")[0].vertices
    check_array_gradient(c, "tendon_stiffness", [t.stiffness for t in c.design.elements("tendon")])
    rows = c.plan.family_controls["tendon"]
    g = c.values["tendon_controls"]
    assert g.shape == rows.shape and g[0, 0] == 0.0  # row 0's controls hold for no step
    for r in sorted({1, len(rows) // 2, len(rows) - 1, int(np.argmax(np.abs(g[:, 0])))}):
        def moved(e, r=r):
            x = rows.copy()
            x[r, 0] += e
            return x
        fd = c.central(1e-8, tendon_controls=moved)
        assert close(g[r, 0], fd, np.abs(g).max()), (r, g[r, 0], fd)
    check_rest_gradient(c, [a, b])


def test_every_rebuild_of_a_design_keeps_every_family_cell_and_flag():
    """Design.replace is the one copy rule: the designer's copies, co-design's trial designs and a
    calibration's design keep every force family's elements, the cells (shared ones stay shared) and
    the per-face stretch scale."""
    from warp_shape.calibration import apply_values
    from warp_shape.designer.codesign import CodesignProblem, CodesignSettings
    from warp_shape.designer.initialize import copy_design
    d, _ = anchored_design()
    add_tendon(d, 0, far_vertex(d.rest, 0))
    d.add_cell([1, 2, 3], shared=True)
    d.add_cell([3, 4], shared=True)
    d.set_stretch_scale(np.linspace(0.9, 1.1, d.rest.n_faces))
    problem = CodesignProblem(d, "rest+ipams", CodesignSettings(), 2.0 * d.rest.volume())
    p = np.full(problem.size, 0.01)
    copies = {"copy_design": copy_design(d), "replace": d.replace(rest=d.rest.scaled(1.01)),
              "calibration": apply_values(d, {"youngs_modulus": 2.0 * d.material.youngs_modulus, "ipam_area": 2e-5}),
              "co-design": problem.design(p)}
    for how, out in copies.items():
        for fam in ("anchor", "tendon"):
            assert out.elements(fam) == d.elements(fam), (how, fam)
        assert [c.faces.tolist() for c in out.cells] == [c.faces.tolist() for c in d.cells], how
        np.testing.assert_array_equal(out.stretch_scale, d.stretch_scale)
        assert out.n_ipams == 1 and out.ipams[0].face_a == d.ipams[0].face_a, how
    assert copies["co-design"].ipams[0].area == pytest.approx(d.ipams[0].area * np.exp(0.01))
    assert copies["calibration"].ipams[0].area == 2e-5
    assert copies["replace"].ipams[0].free_length == pytest.approx(1.01 * d.ipams[0].free_length)  # follows the rest
