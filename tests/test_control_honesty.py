"""What a control result claims is what the device does: one fit objective, PCC 0 without shape,
convergence measured at rest, saturation named, and targets checked against the device first."""

from __future__ import annotations

import json

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.controller import control
from warp_shape.controller.observe import fit_of, vertex_area_shares
from warp_shape.objectives.radial import fit_objective
from warp_shape.scenarios import cube_fig6_design
from conftest import with_pressure_max

# fraction by which holding a converged run's final controls may still change its volume
HOLD_VOLUME_FRACTION = 1e-3


def _replay(res) -> ws.Simulator:
    """A fresh simulator driven by the result's recorded control sequence and jam steps."""
    s, h = res.settings, res.history
    sim = ws.Simulator(res.design, settings=s.simulation)
    n_ipam = len(res.ipam_pressures)
    for k in range(len(h["step"]) - 1):
        for j in np.flatnonzero(res.jam_steps == k):
            sim.jam(int(j))
        sim.air_moles = h["air_mol"][k + 1]
        if n_ipam:
            sim.ipam_pressures = np.array([h[f"ipam{i}_pressure_pa"][k + 1] for i in range(n_ipam)])
        sim.step(s.control_period)
    return sim


@pytest.fixture(scope="module")
def fig6_small():
    """Fig. 6 on a 162-vertex membrane driven to the cube."""
    design = cube_fig6_design(subdivisions=2)
    return design, control(design, ws.target("cube"), method="paper")


# ----------------------------------------------------------------------------------------- metrics
def test_shape_without_spread_has_pcc_zero():
    rest = ws.icosphere(3, 0.035)
    r = np.linalg.norm(rest.vertices.astype(np.float32).astype(np.float64), axis=1)  # equal up to float32 rounding
    assert np.std(r) > 0
    R = np.linalg.norm(ws.radial_sample(ws.target("oval"), rest.vertices), axis=1)
    assert ws.pcc(r, R) == 0.0 and ws.pcc(R, r) == 0.0
    assert ws.pcc(R, R) == pytest.approx(1.0) and ws.pcc(R, -R) == pytest.approx(-1.0)
    # a real shape whose spread is small but well above rounding still correlates
    tiny = r.mean() * (1 + 1e-4 * (R - R.mean()) / R.std())
    assert ws.pcc(tiny, R) == pytest.approx(1.0, abs=1e-6)
    # the controller's first observation is the rest sphere: PCC 0 exactly
    res = control(ws.Design(ws.icosphere(2, 0.035)), ws.target("oval"), method="paper", max_steps=2,
                  max_settle_steps=0)
    assert res.history["pcc"][0] == 0.0


def test_objective_of_sampled_target_and_of_uniform_scale_error():
    oval = ws.target("oval")
    rest = ws.icosphere(3, 0.035)
    sampled = ws.radial_sample(oval, rest.vertices)
    w = vertex_area_shares(sampled[None], rest.faces)[0]
    assert w.sum() == pytest.approx(rest.copy_with(sampled).face_areas().sum(), rel=1e-12)
    R = np.linalg.norm(sampled, axis=1)
    scale = oval.volume() ** (1.0 / 3.0)
    rms_R = np.sqrt(np.sum(w * R * R) / w.sum())
    for s in (1.0, 0.9, 0.97, 1.05):
        fit = fit_of((s * sampled)[None], sampled[None], rest.faces, np.array([oval.volume()]))
        assert fit["objective"][0] == pytest.approx(abs(1 - s) * rms_R / scale, rel=1e-9, abs=1e-15)
        assert fit["mare"][0] == pytest.approx(abs(1 - s) * R.mean(), rel=1e-9, abs=1e-15)
        assert fit["mpre"][0] == pytest.approx(100 * abs(1 - s), rel=1e-9, abs=1e-12)
    assert fit_of(sampled[None], sampled[None], rest.faces, np.array([oval.volume()]))["objective"][0] == 0.0


def test_result_objective_is_the_area_weighted_fit_at_the_end(fig6_small):
    design, res = fig6_small
    x, s = res.achieved.vertices, res.sampled_target.vertices
    w = vertex_area_shares(s[None], design.rest.faces)[0]
    want = fit_objective(np.linalg.norm(x, axis=1), np.linalg.norm(s, axis=1), ws.target("cube").volume(), w)
    assert res.objective == pytest.approx(want, rel=1e-12)
    assert res.objective == res.history["objective"][-1] and res.pcc == res.history["pcc"][-1]
    assert res.history["objective"][-1] < 0.5 * res.history["objective"][0]  # the law improves the fit
    assert res.summary()["objective"] == res.objective


# ----------------------------------------------------------------------------------------- at rest
def test_converged_run_is_at_rest_and_replays(fig6_small):
    design, res = fig6_small
    s = res.settings
    assert res.converged and res.settled and res.saturated == [], res.reason
    assert res.max_speed < s.settle_speed and "at rest" in res.reason
    sim = _replay(res)
    np.testing.assert_allclose(sim.positions, res.achieved.vertices, atol=1e-7)  # the sequence reproduces it
    assert np.linalg.norm(sim.velocities, axis=1).max() < s.settle_speed  # measured by continuing
    v_end = sim.volume()
    sim.step(s.control_period * 50)  # hold the final controls 0.5 s longer
    assert np.linalg.norm(sim.velocities, axis=1).max() < s.settle_speed
    assert abs(sim.volume() / v_end - 1) < HOLD_VOLUME_FRACTION
    assert abs(sim.volume() / res.achieved.volume() - 1) < HOLD_VOLUME_FRACTION
    # the record shows the hold: controls unchanged over the phase-3 rows that end the run
    h = res.history
    hold = np.flatnonzero(h["phase"] == 3)
    assert hold.size and hold[-1] == len(h["phase"]) - 1
    assert np.all(h["air_mol"][hold] == h["air_mol"][hold[0]])


def test_saturated_run_names_the_limit_and_is_not_converged():
    design = with_pressure_max(cube_fig6_design(subdivisions=2), 100e3)
    res = control(design, ws.target("cube"), method="paper")
    corners = [f"ipam {i} at P_max 100 kPa" for i in range(4)]
    assert res.saturated == corners, res.saturated
    assert not res.converged and res.settled
    assert res.reason.startswith("stopped by a limit") and all(c in res.reason for c in corners), res.reason
    assert np.all(res.ipam_pressures[:4] == 100e3)
    # pinned while their targets still ask for longer IPAMs
    h = res.history
    assert all(h[f"ipam{i}_target_length_m"][-1] - h[f"ipam{i}_length_m"][-1] > res.settings.length_deadband
               for i in range(4))
    assert res.summary()["saturated"] == corners and res.summary()["converged"] is False


def test_command_line_reports_objective_and_saturation(tmp_path, capsys):
    from warp_shape.cli import main

    assert main(["control", "--target", "cube", "--method", "paper", "--json", "--out", str(tmp_path)]) == 0
    data = json.loads(capsys.readouterr().out)["cube"]
    for key in ("objective", "pcc", "mare_m", "mpre_pct", "saturated", "converged", "settled", "reason"):
        assert key in data, key
    assert 0 < data["objective"] < 0.1 and data["converged"] is (data["saturated"] == [] and data["settled"])


# ----------------------------------------------------------------------------------------- checks
@pytest.fixture
def no_simulation(monkeypatch):
    """Fail if a control run gets as far as building a simulator: the checks must come first."""
    import warp_shape.controller.loop as loop

    def refuse(*a, **k):
        raise AssertionError("a simulator was built before the target check")

    monkeypatch.setattr(loop, "_simulator", refuse)


@pytest.mark.parametrize("case,match", [
    ("millimetres", "looks like millimetres: scale it by 1e-3"),
    ("too_large", "beyond max_stretch"),
    ("too_small", r"smaller than the rest shape .* initialise the rest shape from the targets \(warp-shape design "
                  r"does; in Python ws\.design\(\.\.\., initialize=True\)\) or use a smaller base"),
    ("inverted", "faces inverted: the rest shape does not surround the target's centre"),
])
def test_targets_checked_against_the_device_first(no_simulation, case, match):
    oval = ws.target("oval")
    rest = {"too_small": ws.icosphere(2, 0.045), "inverted": ws.icosphere(2, 0.02, center=(0.05, 0.0, 0.0))}
    design = ws.Design(rest.get(case, ws.icosphere(2, 0.035)))
    target = {"millimetres": oval.scaled(1e3), "too_large": ws.target("oval", volume=200 * design.rest.volume())}
    with pytest.raises(ws.ShapeError, match=match):
        control(design, target.get(case, oval), target_name="oval")


def test_designer_checks_targets_before_its_first_round(monkeypatch):
    import warp_shape.designer.loop as designer_loop

    def refuse(*a, **k):
        raise AssertionError("a design round ran before the target check")

    monkeypatch.setattr(designer_loop, "control_many", refuse)
    base = ws.icosphere(2, 0.035)
    with pytest.raises(ws.ShapeError, match="looks like millimetres"):  # initialised from millimetre targets
        ws.design(base, [ws.target("oval").scaled(1e3), ws.target("heart").scaled(1e3)], actuators=1)
    with pytest.raises(ws.ShapeError, match=r"smaller than the rest shape.*initialize=True"):
        ws.design(ws.icosphere(2, 0.045), [ws.target("cube")], actuators=1, initialize=False)
