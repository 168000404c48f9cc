"""SPEC section 8: the public names, called exactly as the specification writes them."""

from __future__ import annotations

import numpy as np

import warp_shape as ws


def test_spec_section_8_api(tmp_path):
    mesh = ws.icosphere(subdivisions=2, radius=0.04)
    assert isinstance(mesh, ws.TriMesh)
    assert mesh.vertices.shape[1] == 3 and mesh.vertices.dtype == np.float64
    assert mesh.faces.shape[1] == 3 and mesh.faces.dtype == np.int32
    mesh.to_trimesh().export(str(tmp_path / "m.stl"))
    mesh = ws.TriMesh.load(tmp_path / "m.stl")
    tgt = ws.target("cube")
    assert np.allclose(tgt.centroid(), 0.0, atol=1e-12)
    mat = ws.Material(youngs_modulus=69e3, thickness=2e-3, areal_density=3.5, bending_stiffness=1e-4,
                      spring_damping=5e-3, viscous_damping=2e-2, jam_stretch_factor=10.0, jam_bend_factor=30.0,
                      temperature=293.15, atmospheric_pressure=101325.0)
    d = ws.Design(rest=mesh, material=mat)
    far = int(np.argmin(mesh.face_centroids() @ mesh.face_centroids()[0]))
    i = d.add_ipam(0, far, stiffness=50.0, area=1.5e-5, free_length=None, pressure_limits=(-50e3, 300e3))
    c = d.add_cell([1, 2, 3])
    assert (i, c) == (0, 0)
    sim = ws.Simulator(d, device="cpu", integrator="rk4", dt=1e-3, precision="float32", bending="exact")
    assert sim.positions.shape == (mesh.n_vertices, 3) and sim.velocities.shape == (mesh.n_vertices, 3)
    sim.positions = sim.positions * 1.01
    sim.velocities = np.zeros((mesh.n_vertices, 3))
    sim.air_moles = sim.air_moles * 1.2
    sim.ipam_pressures = np.array([10e3])
    assert isinstance(sim.air_moles, float) and sim.ipam_pressures.shape == (1,)
    sim.jam(c)
    assert sim.jammed.dtype == bool and sim.jammed.tolist() == [True]
    assert sim.forces().shape == (mesh.n_vertices, 3)
    assert sim.ipam_forces().shape == (1,)
    assert sim.volume() > 0 and sim.pressure() > 0
    sim.step(n=1)
    sim.step()
    pts = ws.radial_sample(tgt, mesh.vertices)
    assert pts.shape == (mesh.n_vertices, 3)
    r, R = np.linalg.norm(sim.positions, axis=1), np.linalg.norm(ws.radial_sample(tgt, sim.positions), axis=1)
    assert -1 <= ws.pcc(r, R) <= 1 and ws.mare(r, R) > 0 and ws.mpre(r, R) > 0
    res = ws.control(d, tgt, device="cpu", max_steps=20)
    assert isinstance(res.achieved, ws.TriMesh)
    for name in ("pcc", "mare", "mpre", "volume_error"):
        assert np.isfinite(getattr(res, name))
    assert res.ipam_forces.shape == (1,) and res.jammed.shape == (1,) and len(res.history["pcc"]) > 0
    out = ws.design(ws.icosphere(2, 0.035), [ws.target("oval"), tgt], actuators=1, codesign="off")
    assert isinstance(out.design, ws.Design) and len(out.results) == 2
    assert out.pcc_by_round.shape == (2, 2)
    scene = ws.Scene(design=d, targets=[tgt], settings=None)
    ws.save_scene(scene, tmp_path / "s.usda")
    back = ws.load_scene(tmp_path / "s.usda")
    assert back.design.n_ipams == 1 and back.design.n_cells == 1
    assert ws.load_scene("cube_fig6").design.n_ipams == 5


def test_export_command(tmp_path):
    import trimesh

    from warp_shape.cli import main

    rc = main(["export", "cube_fig6", "--out", str(tmp_path), "--what", "molds", "usd"])
    assert rc == 0
    assert {"mold_core_mm.stl", "mold_shell_top_mm.stl", "design.usda"} <= {p.name for p in tmp_path.iterdir()}
    assert trimesh.load(tmp_path / "mold_shell_top_mm.stl").is_watertight
    assert ws.load_scene(tmp_path / "design.usda").design.n_ipams == 5
    assert main(["export", "target_oval", "--out", str(tmp_path / "x")]) == 2  # no design in a target scene
