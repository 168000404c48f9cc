"""The controller (paper section IV-B): inflation, the Fig. 6 cube case, path dependence, records."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.controller import ControlSettings, control, control_many
from warp_shape.io.outputs import write_control_outputs, write_control_usd
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulation_settings import SimulationSettings


@pytest.fixture(scope="module")
def fig6():
    """Fig. 6: sphere, four corner IPAMs + one face IPAM, a cell at every end; 2562 vertices so the
    radial sampling does not cut the cube's corners by more than a fraction of a percent."""
    design = cube_fig6_design(subdivisions=4)
    cube = ws.target("cube")
    return design, cube, control(design, cube, method="paper")


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_inflation_only_reaches_target_volume_without_overshoot(precision):
    design = ws.Design(ws.icosphere(3, 0.035))
    oval = ws.target("oval")
    res = control(design, oval, method="paper", simulation=SimulationSettings(precision=precision))
    h = res.history
    assert res.converged and res.settled and not res.saturated, res.reason
    # measured at rest: the volume of the sampled target (the volume eq. (11) drives to) within its deadband
    assert abs(res.volume_error) < res.settings.volume_deadband
    assert abs(res.achieved.volume() / res.sampled_target.volume() - 1) < res.settings.volume_deadband
    assert abs(res.sampled_target.volume() / oval.volume() - 1) < 0.01  # 642 samples cut the oval by < 1 %
    # never more than one rate-limited air increment past the target
    overshoot = (h["volume_m3"] / h["target_volume_m3"]).max() - 1
    assert overshoot < res.settings.volume_deadband + 0.002, overshoot
    dn = np.diff(h["air_mol"])
    assert np.abs(dn).max() <= res.settings.air_rate * h["air_mol"][0] * (1 + 1e-9)


def test_fig6_cube(fig6):
    design, cube, res = fig6
    h = res.history
    assert res.converged and res.settled and res.saturated == [], res.reason
    assert abs(res.achieved.volume() / cube.volume() - 1) < 0.01
    assert abs(res.volume_error) < 0.01
    # PCC after the whole sequence clearly above the PCC after inflation alone
    after_inflation = h["pcc"][np.flatnonzero(h["phase"] == 2)[0]]
    assert res.pcc > after_inflation + 0.3 and res.pcc > 0.85, (res.pcc, after_inflation)
    # paper, section IV-C: corner IPAMs in compression, the face IPAM in tension, pushes larger
    assert np.all(res.ipam_forces[:4] < 0) and res.ipam_forces[4] > 0
    assert np.abs(res.ipam_forces[:4]).min() > res.ipam_forces[4]
    # every cell jams at most once and never unjams
    for j in range(design.n_cells):
        col = h[f"cell{j}_jammed"]
        assert np.all(np.diff(col) >= 0)
        if res.jammed[j]:
            assert res.jam_steps[j] >= 0 and h["phase"][res.jam_steps[j]] == 2
    assert res.jammed.any()
    # the jam rule's last curvature starts at the first shape-control step: no cell jams there
    first_shaping = int(h["step"][np.flatnonzero(h["phase"] == 2)[0]])
    assert np.all((res.jam_steps < 0) | (res.jam_steps > first_shaping)), res.jam_steps


def test_fig6_actuator_summary(fig6):
    _, _, res = fig6
    summary = res.actuator_summary
    assert len(summary) == 5
    for i, s in enumerate(summary):
        assert s["pressure_min_pa"] <= s["pressure_max_pa"]
        assert s["peak_push_n"] >= 0 and s["peak_pull_n"] >= 0 and s["peak_strain"] > 0
    assert all(summary[i]["peak_push_n"] > summary[4]["peak_pull_n"] for i in range(4))


def test_history_exports(fig6, tmp_path):
    design, _, res = fig6
    n_rows = res.control_steps + 1
    assert all(len(v) == n_rows for v in res.history.values())
    expected = {"step", "time", "phase", "air_mol", "pressure_pa", "volume_m3", "target_volume_m3", "pcc", "mare_m",
                "mpre_pct", "objective", "max_speed_m_s", "ipam0_pressure_pa", "ipam0_length_m", "ipam0_target_length_m", "ipam0_force_n",
                "ipam0_strain", "cell0_kappa_m", "cell0_kappa_target_m", "cell0_jammed"}
    assert expected <= set(res.history)
    paths = write_control_outputs([res], ["cube"], tmp_path)
    assert [p.name for p in paths] == ["control_cube.csv", "control_cube.json"]
    with open(tmp_path / "control_cube.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == n_rows
    assert float(rows[-1]["pcc"]) == pytest.approx(res.history["pcc"][-1], rel=1e-6)
    data = json.loads((tmp_path / "control_cube.json").read_text())
    assert data["columns"] == list(res.history) and len(data["rows"]) == n_rows
    assert data["converged"] is res.converged and data["saturated"] == res.saturated
    assert data["objective"] == pytest.approx(res.objective) and data["settled"] is True
    assert not list(tmp_path.glob(".*"))


def test_path_dependence_jamming_matters():
    design = cube_fig6_design(subdivisions=3)
    cube = ws.target("cube")
    with_rule = control(design, cube, method="paper")
    without = control(design, cube, method="paper", jamming=False)
    assert not without.jammed.any() and with_rule.jammed.any()
    diff = np.linalg.norm(with_rule.achieved.vertices - without.achieved.vertices, axis=1).max()
    assert diff > 3e-4, "jamming must change the achieved shape"
    assert with_rule.objective < without.objective and with_rule.pcc > without.pcc + 0.005, \
        (with_rule.objective, without.objective, with_rule.pcc, without.pcc)


def test_determinism():
    design = cube_fig6_design(subdivisions=2)
    cube = ws.target("cube")
    a = control(design, cube, method="paper", max_steps=15)
    b = control(design, cube, method="paper", max_steps=15)
    assert a.history.keys() == b.history.keys()
    for k in a.history:
        np.testing.assert_array_equal(a.history[k], b.history[k], err_msg=k)


def test_batch_of_targets():
    design = cube_fig6_design(subdivisions=2)
    results = control_many(design, [ws.target("cube"), ws.target("oval")], method="paper", max_steps=60)
    assert len(results) == 2
    for r in results:
        assert abs(r.volume_error) < 0.01 and np.all(np.isfinite(r.achieved.vertices))


def test_bad_targets_and_designs():
    design = ws.Design(ws.icosphere(2, 0.03))
    ring = ws.TriMesh(*_torus())
    with pytest.raises(ws.ShapeError, match="not star-shaped"):
        control(design, ring)
    with pytest.raises(ws.DesignError, match="ends coincide"):
        design.add_ipam(4, 4)
    with pytest.raises(ws.DesignError, match="unknown controller setting"):
        control(design, ws.target("oval"), bogus=1)


def test_step_limit_is_reported_and_measured_at_rest():
    design = ws.Design(ws.icosphere(2, 0.03))
    res = control(design, ws.target("oval"), method="paper", max_steps=5)
    assert not res.converged and res.reason.startswith("step limit reached (5 control steps)"), res.reason
    h = res.history
    assert np.count_nonzero(h["phase"] != 3) == 5  # five steps of the law, then the controls held
    assert res.settled and res.max_speed < res.settings.settle_speed and "at rest" in res.reason
    assert h["air_mol"][-1] == h["air_mol"][5]  # held
    res = control(design, ws.target("oval"), method="paper", max_steps=5, max_settle_steps=0)
    assert not res.settled and "not at rest" in res.reason and res.max_speed > res.settings.settle_speed


def _torus(R=0.03, r=0.01, n=24, m=12):
    u, v = np.meshgrid(np.arange(n) * 2 * np.pi / n, np.arange(m) * 2 * np.pi / m, indexing="ij")
    pts = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1).reshape(-1, 3)
    idx = lambda i, j: (i % n) * m + (j % m)  # noqa: E731
    faces = []
    for i in range(n):
        for j in range(m):
            faces += [[idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]]
    return pts, np.array(faces)


def test_controlled_run_exports_animated_usd(fig6, tmp_path):
    from pxr import Usd, UsdGeom

    design, _, res = fig6
    for ext in ("usda", "usdc"):
        path = write_control_usd(res, tmp_path / f"run.{ext}", target_name="cube")
        stage = Usd.Stage.Open(str(path))
        animated = [UsdGeom.Mesh(p) for p in stage.Traverse()
                    if p.IsA(UsdGeom.Mesh) and UsdGeom.Mesh(p).GetPointsAttr().GetNumTimeSamples() > 0]
        assert len(animated) == 1  # the membrane; the target ghost is static
        mesh = animated[0]
        samples = mesh.GetPointsAttr().GetTimeSamples()
        assert len(samples) == len(res.frames) == res.control_steps + 1
        last = np.array(mesh.GetPointsAttr().Get(samples[-1]))
        np.testing.assert_allclose(last, res.achieved.vertices, atol=1e-7)
        assert ws.validate_usd(path) == []


def test_coarse_membrane_does_not_oscillate():
    """A 162-vertex membrane settles slower than a control period: for this design (the designer's
    first oval/heart actuator) eqs. (11)-(12) alone overshoot into a sustained period-2 volume
    oscillation; gain back-off must make the run converge."""
    from warp_shape.designer import design as run_design

    d1 = run_design(ws.icosphere(2, 0.035), [ws.target("oval"), ws.target("heart")], actuators=1,
                    target_names=["oval", "heart"], control_settings=ControlSettings(method="paper"),
                    codesign="off").designs[1]
    heart = ws.target("heart")
    plain = control(d1, heart, method="paper", max_steps=120, gain_backoff=1.0)  # the paper's laws as they are
    law = plain.history["phase"] != 3  # the steps at which the law acted
    v = plain.history["volume_m3"][law][-10:] / plain.history["target_volume_m3"][law][-10:] - 1
    assert not plain.converged and np.ptp(v) > 0.05  # alternating by more than 5 % of the volume
    res = control(d1, heart, method="paper", max_steps=120)
    assert res.converged, res.reason
    v = res.history["volume_m3"][-3:] / res.history["target_volume_m3"][-3:] - 1
    assert np.abs(v).max() < 0.01


def test_settings_hold_simulation_options():
    s = ControlSettings()
    assert s.simulation == SimulationSettings()
    t = s.replace(max_steps=5, simulation=SimulationSettings(precision="float64", dt=5e-4))
    assert t.max_steps == 5 and t.simulation.precision == "float64" and t.simulation.dt == 5e-4
    with pytest.raises(ws.DesignError, match="unknown controller setting"):
        s.replace(dt=1e-3)  # simulation options live in settings.simulation
    with pytest.raises(ws.DesignError, match="SimulationSettings"):
        ControlSettings(simulation={"dt": 1e-3})
