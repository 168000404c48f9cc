"""Bad input gets a clear error naming the problem; blow-ups are detected, never returned as NaN."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import warp_shape as ws


def _sphere():
    return ws.icosphere(1, 0.04)


def test_open_mesh_rejected():
    m = _sphere()
    with pytest.raises(ws.MeshError, match="not closed: open boundary at edge"):
        ws.TriMesh(m.vertices, m.faces[1:])


def test_non_manifold_edge_rejected():
    m = _sphere()
    f = m.faces
    # a fin: a third face on an existing edge
    extra = np.array([[f[0, 0], f[0, 1], m.n_vertices]])
    v = np.vstack([m.vertices, [[0.0, 0.0, 0.1]]])
    with pytest.raises(ws.MeshError, match=r"not 2-manifold: edge \(\d+, \d+\).*shared by 4 faces"):
        ws.TriMesh(v, np.vstack([f, extra, extra[:, ::-1]]))


def test_flipped_face_rejected():
    m = _sphere()
    f = m.faces.copy()
    f[5] = f[5, ::-1]
    with pytest.raises(ws.MeshError, match="inconsistent winding: faces .* same direction"):
        ws.TriMesh(m.vertices, f)


def test_inside_out_mesh_rejected():
    m = _sphere()
    with pytest.raises(ws.MeshError, match="wound inward"):
        ws.TriMesh(m.vertices, m.faces[:, ::-1])


def test_zero_area_face_rejected():
    m = _sphere()
    v = m.vertices.copy()
    a, b, c = m.faces[3]
    v[c] = 0.5 * (v[a] + v[b])  # collapse face 3 onto its edge
    with pytest.raises(ws.MeshError, match="degenerate triangle: face 3 .* zero area"):
        ws.TriMesh(v, m.faces)


def test_nan_vertex_rejected():
    m = _sphere()
    v = m.vertices.copy()
    v[7, 1] = np.nan
    with pytest.raises(ws.MeshError, match="vertex 7 is not finite"):
        ws.TriMesh(v, m.faces)


def test_two_parts_rejected():
    a, b = ws.icosphere(0, 0.01), ws.icosphere(0, 0.01, center=(0.1, 0, 0))
    with pytest.raises(ws.MeshError, match="2 separate parts"):
        ws.TriMesh(np.vstack([a.vertices, b.vertices]), np.vstack([a.faces, b.faces + a.n_vertices]))


@pytest.mark.parametrize("field,value,match", [("youngs_modulus", -1.0, "youngs_modulus must be > 0"),
                                               ("thickness", 0.0, "thickness must be > 0"),
                                               ("areal_density", float("nan"), "finite number"),
                                               ("jam_stretch_factor", 0.5, ">= 1"),
                                               ("viscous_damping", -0.1, ">= 0")])
def test_bad_material_rejected(field, value, match):
    with pytest.raises(ws.DesignError, match=match):
        ws.Material(**{field: value})


def test_bad_actuators_rejected():
    d = ws.Design(_sphere())
    with pytest.raises(ws.DesignError, match="ends coincide"):
        d.add_ipam(3, 3)
    f0 = d.rest.faces[0]
    touching = int(np.flatnonzero((d.rest.faces == f0[0]).any(axis=1))[1])
    with pytest.raises(ws.DesignError, match="share vertex"):
        d.add_ipam(0, touching)
    with pytest.raises(ws.DesignError, match="out of range"):
        d.add_ipam(0, 10_000)
    far = int(np.argmin(d.rest.face_centroids() @ d.rest.face_centroids()[0]))
    with pytest.raises(ws.DesignError, match="below full vacuum"):
        d.add_ipam(0, far, pressure_limits=(-2e5, 1e5))
    d.add_cell([1, 2])
    with pytest.raises(ws.DesignError, match="already belongs to cell 0"):
        d.add_cell([2, 3])
    sim = ws.Simulator(ws.Design(_sphere()))
    with pytest.raises(ws.DesignError, match="no IPAMs"):
        sim.ipam_pressures = [1.0]
    d2 = ws.Design(_sphere())
    d2.add_ipam(0, far, pressure_limits=(0.0, 1e5))
    sim2 = ws.Simulator(d2)
    with pytest.raises(ws.DesignError, match="outside its limits"):
        sim2.ipam_pressures = [2e5]
    with pytest.raises(ws.DesignError, match="cell must be an index"):
        sim2.jam(0)


def test_bad_simulator_arguments():
    d = ws.Design(_sphere())
    with pytest.raises(ws.DesignError, match="unknown integrator"):
        ws.Simulator(d, integrator="leapfrog9")
    with pytest.raises(ws.DesignError, match="precision must be one of"):
        ws.Simulator(d, precision="float16")
    with pytest.raises(ws.DesignError, match="not available"):
        ws.Simulator(d, device="cuda:7")
    with pytest.raises(ws.DesignError, match="dt must be a positive"):
        ws.Simulator(d, dt=0.0)
    sim = ws.Simulator(d)
    with pytest.raises(ws.DesignError, match="positions must be finite"):
        sim.positions = np.full((d.rest.n_vertices, 3), np.nan)
    with pytest.raises(ws.DesignError, match="air_moles must be >= 0"):
        sim.air_moles = -1.0


def test_fixed_substep_dt_beyond_estimate_refused():
    d = ws.Design(_sphere())
    est = ws.Simulator(d).stable_dt()
    with pytest.raises(ws.StabilityError, match=r"beyond the stable step estimate .* use dt <= "):
        ws.Simulator(d, dt=1.5 * est, substeps=1)
    ws.Simulator(d, dt=0.9 * est, substeps=1).step(5)  # just below: accepted
    # automatic substeps split the same dt instead
    sim = ws.Simulator(d, dt=1.5 * est)
    assert sim.substeps == 2 and sim.internal_dt <= est


def test_jam_beyond_estimate_refused_with_fixed_substeps():
    rest = _sphere()
    d = ws.Design(rest)
    d.add_cell(np.arange(rest.n_faces))
    est = ws.Simulator(d).stable_dt()
    sim = ws.Simulator(d, dt=0.9 * est, substeps=1)
    sim.jam(0)  # x10 stiffness: ~3x smaller stable step
    with pytest.raises(ws.StabilityError, match="safe|use dt"):
        sim.step()


def test_blowup_is_reported_with_step_and_quantity():
    # fixed substeps: no retry with shorter steps (which would take the step again from the last good state)
    sim = ws.Simulator(ws.Design(_sphere()), substeps=1)
    sim.step(3)
    x = sim.state.x.numpy()
    x[0, 5, 0] = np.nan  # corrupt the state behind the API's back
    sim.state.x.assign(x)
    with pytest.raises(ws.SimulationError, match=r"blew up at output step 4 .*positions became non-finite") as info:
        sim.step(1)
    assert info.value.step == 4 and info.value.quantity == "positions" and info.value.safe_dt > 0


def _corrupt(sim, world, vertex):
    x = sim.state.x.numpy()
    x[world, vertex, 0] = np.nan  # corrupt the state behind the API's back
    sim.state.x.assign(x)


def test_deferred_blowup_check_names_the_first_step():
    """The GPU path (codes noted on the device, read once per call) names the same output step as the
    per-step check, here from the middle of a longer call, in the world that blew up first."""
    from warp_shape.integrators import BlowupWatch

    sim = ws.Simulator(ws.Design(_sphere()), worlds=3)
    sim.blowup_watch = BlowupWatch(sim.solver.status, deferred=True)
    sim.step(3)
    _corrupt(sim, 2, 5)
    with pytest.raises(ws.SimulationError, match=r"blew up at output step 4 .*world 2\).*positions became non-finite") as info:
        sim.step(6)
    assert info.value.step == 4 and info.value.world == 2 and info.value.quantity == "positions"
    # the device ran on to the end of the call before the host looked; the call is undone whole: the
    # state, step count and time are those before the call (the state corrupted behind the API's back)
    assert sim.step_count == 3 and sim.time == pytest.approx(3 * sim.dt)
    assert f"t = {4 * sim.dt:.6g} s" in str(info.value)
    # reported once: the notes and codes are cleared
    assert np.all(sim.blowup_watch.first_step.numpy() == -1) and not sim.solver.status.numpy().any()


def test_deferred_blowup_check_reports_before_a_reestimate():
    """A re-estimate of the stable step reads the state: a blow-up noted before it is reported first."""
    from warp_shape.integrators import BlowupWatch

    sim = ws.Simulator(ws.Design(_sphere()), dt=2e-4, substeps=1, reestimate_every=2)
    sim.blowup_watch = BlowupWatch(sim.solver.status, deferred=True)
    sim.step(1)
    _corrupt(sim, 0, 3)
    with pytest.raises(ws.SimulationError, match=r"blew up at output step 2 ") as info:
        sim.step(10)
    assert info.value.step == 2  # found at the re-estimate before step 3, not later
    assert sim.step_count == 1  # and the call undone whole (deferred checks restore the state before the call)


def test_runaway_speed_is_reported():
    sim = ws.Simulator(ws.Design(_sphere()))
    v = np.zeros((sim.model.n_vertices, 3))
    v[0] = [1e5, 0, 0]
    sim.velocities = v
    with pytest.raises(ws.SimulationError, match="ran away"):
        sim.step(1)
