"""Rerun recordings: what a control run and a design run log, read back from the .rrd."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.scenarios import cube_fig6_design

rr = pytest.importorskip("rerun")
from launch_counter import count_control_launches  # noqa: E402
from warp_shape.io.recorder import Recorder, diverging_colors  # noqa: E402
from warp_shape.io.recording_read import read_recording  # noqa: E402


@pytest.fixture(scope="module")
def fig6():
    return cube_fig6_design(subdivisions=2)


@pytest.fixture(scope="module")
def recorded(fig6, tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    with Recorder(path) as rec:
        res = ws.control(fig6, ws.target("cube"), max_steps=20, recorder=rec, target_name="cube")
    return path, res, read_recording(path)


def test_control_run_frames_positions_and_pcc_read_back(recorded):
    path, res, rec = recorded
    assert path.exists() and not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp left
    ents = rec["entities"]
    n = len(res.history["step"])
    mem = ents["/control/cube/membrane"]
    assert len(mem["Mesh3D:vertex_positions"]) == n  # one frame per control step
    np.testing.assert_array_equal(mem["times"]["control_step"], res.history["step"])
    np.testing.assert_allclose(mem["times"]["sim_time"], res.history["time"], atol=1e-9)
    # topology once (static), positions per frame
    np.testing.assert_array_equal(mem["static"]["Mesh3D:triangle_indices"], res.design.rest.faces)
    assert "Mesh3D:triangle_indices" not in mem
    last = mem["Mesh3D:vertex_positions"][-1]
    np.testing.assert_allclose(last, res.achieved.vertices, rtol=0, atol=1e-7)  # stored as float32
    # colour = radial error to the sampled target, blue inside / red outside
    err = np.linalg.norm(res.achieved.vertices, axis=1) - np.linalg.norm(res.sampled_target.vertices, axis=1)
    packed = diverging_colors(err, 5e-3).view(">u4")[:, 0]  # rerun packs RGBA as 0xRRGGBBAA
    np.testing.assert_array_equal(mem["Mesh3D:vertex_colors"][-1], packed)
    assert (err > 0).any() and (err < 0).any()
    pcc = ents["/control/cube/fit/pcc"]["Scalars:scalars"]
    assert len(pcc) == n
    assert pcc[-1][0] == pytest.approx(res.history["pcc"][-1], abs=1e-12)
    assert pcc[-1][0] == pytest.approx(res.pcc, abs=1e-9)
    vol = ents["/control/cube/volume"]["Scalars:scalars"][-1]
    assert vol == pytest.approx([res.history["volume_m3"][-1], res.history["target_volume_m3"][-1]])
    lengths = ents["/control/cube/ipam/length"]["Scalars:scalars"][-1]
    assert len(lengths) == 2 * res.design.n_ipams
    assert lengths[0] == pytest.approx(res.history["ipam0_length_m"][-1])
    kappa = ents["/control/cube/cell/kappa"]["Scalars:scalars"][-1]
    assert len(kappa) == 2 * res.design.n_cells
    assert len(ents["/control/cube/ipams"]["LineStrips3D:strips"][-1]) == res.design.n_ipams
    assert "Mesh3D:albedo_factor" in ents["/control/cube/target"]["static"]  # the ghost, static only


def test_recording_carries_the_blueprint(recorded):
    _, _, rec = recorded
    assert {"3D", "TimeSeries"} <= set(rec["blueprint"])
    origins = {(c, o) for c, _, o in rec["blueprint_views"]}
    assert ("3D", "/control") in origins


def test_every_decimates_but_keeps_the_last_state(fig6, tmp_path):
    with Recorder(tmp_path / "every.rrd", every=4) as rec:
        res = ws.control(fig6, ws.target("cube"), method="paper", max_steps=10, recorder=rec, target_name="cube")
    mem = read_recording(tmp_path / "every.rrd")["entities"]["/control/cube/membrane"]
    steps = list(mem["times"]["control_step"])
    last = int(res.history["step"][-1])
    expected = sorted(set(range(0, last + 1, 4)) | {last})
    assert steps == expected
    np.testing.assert_allclose(mem["Mesh3D:vertex_positions"][-1], res.achieved.vertices, atol=1e-7)


def test_no_extra_launches_with_or_without_a_recorder(fig6, tmp_path):
    kw = dict(max_steps=8, target_name="cube", method="paper")
    without = count_control_launches(fig6, ws.target("cube"), **kw)
    with Recorder(tmp_path / "l.rrd") as rec:
        with_rec = count_control_launches(fig6, ws.target("cube"), recorder=rec, **kw)
    assert without > 0 and with_rec == without


def test_design_run_logs_every_round_and_the_pcc_table(tmp_path):
    path = tmp_path / "design.rrd"
    names = ["oval", "heart"]
    with Recorder(path, every=10) as rec:
        out = ws.design(ws.icosphere(2, 0.035), [ws.target("oval"), ws.target("heart")], actuators=1,
                        target_names=names, recorder=rec, codesign="off")  # the rounds as placed
    ents = read_recording(path)["entities"]
    for i in range(2):
        for n in names:
            assert f"/design/round_{i}/{n}/membrane" in ents
            assert f"/design/round_{i}/{n}/fit/pcc" in ents
    assert "/design/round_1/oval/ipams" in ents and "/design/round_0/oval/ipams" not in ents  # round 0: no IPAM
    for j, n in enumerate(names):
        e = ents[f"/design/pcc/{n}"]
        np.testing.assert_array_equal(e["times"]["round"], [0, 1])
        np.testing.assert_allclose([v[0] for v in e["Scalars:scalars"]], out.pcc_by_round[:, j])
    # the last logged frame of the final round is the achieved shape of the final design
    mem = ents["/design/round_1/heart/membrane"]
    np.testing.assert_allclose(mem["Mesh3D:vertex_positions"][-1], out.results[1].achieved.vertices, atol=1e-7)


def test_plain_simulation_frames(tmp_path):
    d = cube_fig6_design(subdivisions=2)
    sim = ws.Simulator(d)
    with Recorder(tmp_path / "sim.rrd") as rec:
        rec.begin_simulation(d)
        for k in range(3):
            sim.air_moles = sim.air_moles * 1.05
            sim.step(5)
            rec.log_sim_frame(k, sim.time, sim.positions, sim.volume(), sim.pressure(), sim.ipam_lengths(),
                              sim.ipam_forces(), sim.jammed)
    ents = read_recording(tmp_path / "sim.rrd")["entities"]
    mem = ents["/simulate/world0/membrane"]
    np.testing.assert_array_equal(mem["times"]["sim_step"], [0, 1, 2])
    np.testing.assert_allclose(mem["Mesh3D:vertex_positions"][-1], sim.positions, atol=1e-7)
    assert ents["/simulate/world0/volume"]["Scalars:scalars"][-1][0] == pytest.approx(sim.volume())
    assert len(ents["/simulate/world0/ipam/force"]["Scalars:scalars"][-1]) == d.n_ipams


def test_bad_every_is_refused():
    with pytest.raises(ws.DesignError, match="every"):
        Recorder(every=0)


def test_in_memory_recording_and_two_recorders_side_by_side(fig6, tmp_path):
    mem, filed = Recorder(), Recorder(tmp_path / "f.rrd", every=2)
    ws.control_many(fig6, [ws.target("cube"), ws.target("oval")], method="paper", max_steps=3, recorder=mem,
                    target_names=["cube", "oval"])
    ws.control(fig6, ws.target("cube"), method="paper", max_steps=3, recorder=filed, target_name="cube")
    mem.close()
    filed.close()
    (tmp_path / "m.rrd").write_bytes(mem.memory_bytes())
    got = read_recording(tmp_path / "m.rrd")["entities"]
    assert "/control/oval/membrane" in got and "/control/cube/membrane" in got
    assert list(read_recording(tmp_path / "f.rrd")["entities"]) and "/control/oval/membrane" not in \
        read_recording(tmp_path / "f.rrd")["entities"]


def test_report_figures_are_static_images_in_the_recording(fig6, tmp_path):
    """The report's figures (the rest shape, each target's fit) go into the recording as the same PNGs."""
    pytest.importorskip("matplotlib")
    from warp_shape.io.figures import build_rest_figure

    png = tmp_path / "rest_shape.png"
    build_rest_figure(fig6).savefig(png, format="png", dpi=60)
    path = tmp_path / "figs.rrd"
    with Recorder(path) as rec:
        rec.log_figures([png])
    ent = read_recording(path)["entities"]["/design/figures/rest_shape"]["static"]
    blob = [v for k, v in ent.items() if k.endswith("blob")][0]
    assert bytes(np.asarray(blob, dtype=np.uint8)) == png.read_bytes()
