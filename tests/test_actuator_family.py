"""A second actuator family from outside the package (tests/toy_family.py, a tendon): registered,
stepped, saved to a scene and read back, and held neutral by the paper's control law."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from energy_check import assert_force_is_minus_energy_gradient
from toy_family import TENDON, add_tendon
from warp_shape.force_family import ACTUATOR_FAMILIES
from warp_shape.errors import DesignError
from warp_shape.io.outputs import write_control_outputs


@pytest.fixture(autouse=True)
def tendon_family():
    """The toy family registered for each test of this module (and removed after)."""
    ACTUATOR_FAMILIES.register(TENDON, replace=True)
    yield TENDON
    ACTUATOR_FAMILIES.unregister(TENDON.name)


def far_vertices(mesh) -> tuple[int, int]:
    """Vertex 0 and the vertex at about a quarter turn around the sphere from it."""
    u = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return 0, int(np.argmin(np.abs(u @ u[0])))


def tendon_design(rest_length=None):
    design = ws.Design(ws.icosphere(1, 0.04))
    a, b = far_vertices(design.rest)
    add_tendon(design, a, b, stiffness=20.0, rest_length=rest_length)
    return design, a, b


def test_tendon_force_is_minus_the_gradient_of_its_energy():
    design, a, b = tendon_design()
    sim = ws.Simulator(design, precision="float64")
    assert sim.design.n_ipams == 0 and [f.name for f in sim.model.families] == ["ipam", "tendon"]
    sim.set_actuator_controls("tendon", [0.6 * np.linalg.norm(design.rest.vertices[b] - design.rest.vertices[a])])
    rng = np.random.default_rng(1)
    x0 = design.rest.vertices + 1e-4 * rng.standard_normal(design.rest.vertices.shape)
    sim.positions = x0
    force = sim.forces("tendon")
    assert np.abs(force[a]).max() > 1e-2  # a stretched tendon pulls
    assert_force_is_minus_energy_gradient(sim, "tendon", x0, (a, b))
    others = np.delete(np.arange(design.rest.n_vertices), [a, b])
    assert np.all(force[others] == 0)
    assert np.allclose(force[a], -force[b])
    sim.positions = x0
    sim.set_actuator_mask("tendon", np.array([False]))  # masked out: no force, no energy
    assert sim.actuator_mask("tendon").tolist() == [False]
    assert np.all(sim.forces("tendon") == 0) and sim.energy()["tendon"] == 0


def test_a_shortened_tendon_draws_its_vertices_together():
    design, a, b = tendon_design()
    rest = float(np.linalg.norm(design.rest.vertices[b] - design.rest.vertices[a]))
    distance = {}
    for frac in (1.0, 0.5):
        sim = ws.Simulator(design)
        sim.set_actuator_controls("tendon", [frac * rest])
        assert "eval_tendon_kernel" in " ".join(sim.step_kernels)
        sim.step(20)
        x = sim.positions
        assert np.all(np.isfinite(x))
        distance[frac] = float(np.linalg.norm(x[b] - x[a]))
    assert distance[1.0] == pytest.approx(rest, rel=1e-3)  # at its rest length: no force
    assert distance[0.5] < rest - 1e-3  # shortened: the ends came closer by over a millimetre
    assert np.asarray(sim.actuator_controls("tendon")) == pytest.approx([0.5 * rest])


def test_tendon_controls_are_checked():
    design, _, _ = tendon_design()
    sim = ws.Simulator(design)
    with pytest.raises(DesignError, match="tendon controls must have shape"):
        sim.set_actuator_controls("tendon", [0.01, 0.02])
    with pytest.raises(DesignError, match="no actuators of family 'rope'"):
        sim.actuator_controls("rope")


def test_tendon_round_trips_through_a_scene(tmp_path):
    design, a, b = tendon_design(rest_length=0.03)
    c = design.rest.face_centroids()
    design.add_ipam(5, int(np.argmin(c @ c[5])))
    path = ws.save_scene(ws.Scene(design=design), tmp_path / "tendon.usda")
    text = path.read_text()
    assert "def BasisCurves \"Tendons\"" in text and "warpShape:restLength = [0.03]" in text
    back = ws.load_scene(path).design
    (t,) = back.elements("tendon")
    assert t == design.elements("tendon")[0] and t.vertices == (a, b)
    assert back.n_ipams == 1 and back.ipams[0].face_a == 5
    # a scene with tendons read where the family is not registered: the tendons are not read
    ACTUATOR_FAMILIES.unregister("tendon")
    assert ws.load_scene(path).design.elements("tendon") == []


def test_paper_law_holds_an_unknown_family_neutral(tmp_path):
    design, a, b = tendon_design()
    design.add_cell([0, 1, 2])
    res = ws.control(design, ws.target("oval"), method="paper", max_steps=4, max_settle_steps=2)
    h = res.history
    assert np.all(np.isfinite(h["tendon0_length_m"])) and np.all(np.isfinite(h["objective"]))
    assert np.isfinite(res.objective)
    # every step of the law sets the rest length to the length just observed: no tendon force
    law = h["phase"][:-1] != 3
    assert np.array_equal(h["tendon0_rest_length_m"][1:][law], h["tendon0_length_m"][:-1][law])
    assert h["tendon0_length_m"][-1] != h["tendon0_length_m"][0]  # the membrane moved it
    # the record's columns reach the control files as the IPAM's do
    csv_path = next(p for p in write_control_outputs([res], ["oval"], tmp_path) if p.suffix == ".csv")
    header = csv_path.read_text().splitlines()[0].split(",")
    assert "tendon0_rest_length_m" in header and "tendon0_length_m" in header


def test_a_registered_family_leaves_designs_without_it_unchanged():
    """A design without tendons builds the same model (families, step kernels, energy terms) whether
    or not the tendon family is registered."""
    design = ws.Design(ws.icosphere(1, 0.04))
    c = design.rest.face_centroids()
    design.add_ipam(0, int(np.argmin(c @ c[0])))
    seen = []
    for registered in (True, False):
        if not registered:
            ACTUATOR_FAMILIES.unregister("tendon")
        sim = ws.Simulator(design)
        sim.ipam_pressures = [2e4]
        sim.step(3)
        seen.append(([f.name for f in sim.model.families], sim.step_kernels, sorted(sim.energy()), sim.positions))
    assert seen[0][:3] == seen[1][:3] == (["ipam"], seen[1][1], sorted(seen[1][2]))
    assert "tendon" not in seen[0][2] and "ipam" in seen[0][2]
    assert np.array_equal(seen[0][3], seen[1][3])
    assert ws.ACTUATOR_FAMILIES.get("ipam").summary and isinstance(TENDON, ws.ActuatorFamily)


def test_tendon_controls_move_between_simulators_and_bound_the_stable_step():
    design, a, b = tendon_design()
    src = ws.Simulator(design, worlds=2)
    src.set_actuator_controls("tendon", [[0.02], [0.03]])
    dst = ws.Simulator(design, worlds=2)
    dst.load_worlds(src.snapshot()[::-1])  # world 1 into world 0 and back
    assert np.asarray(dst.actuator_controls("tendon")).tolist() == [[0.03], [0.02]]
    stiff, _, _ = tendon_design()
    stiff.elements("tendon").clear()
    add_tendon(stiff, a, b, stiffness=2e5)
    assert ws.Simulator(stiff).stable_dt() < 0.5 * ws.Simulator(design).stable_dt()  # its rows are in the bound


def test_tendon_values_that_do_not_fit_the_precision_are_refused():
    design, a, b = tendon_design()
    design.elements("tendon").clear()
    add_tendon(design, a, b, stiffness=1e300)
    with pytest.raises(DesignError, match=r"toy_family.add_tendon stiffness = 1e\+300 \(SI\) does not fit in float32"):
        ws.Simulator(design)


def test_tendon_curves_follow_the_membrane_in_an_animation(tmp_path):
    from pxr import Usd

    design, a, b = tendon_design()
    sim = ws.Simulator(design)
    sim.set_actuator_controls("tendon", [0.02])
    frames = [sim.positions]
    for _ in range(2):
        sim.step(5)
        frames.append(sim.positions)
    path = ws.export_animation(tmp_path / "tendon_anim.usda", design, np.stack(frames), [0.0, 0.005, 0.01])
    stage = Usd.Stage.Open(str(path))
    points = stage.GetPrimAtPath("/Scene/Tendons").GetAttribute("points")
    samples = points.GetTimeSamples()
    assert len(samples) == 3
    last = np.array(points.Get(samples[-1]))
    assert np.allclose(last, np.stack(frames)[-1][[a, b]], atol=1e-6)
    assert not np.allclose(last, np.array(points.Get(samples[0])))
