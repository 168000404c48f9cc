"""Co-design: the rest shape and the IPAM sizes descended by the replay's gradients, never worse.

Targets the project does not ship (an egg and a tilted ellipsoid), a 162-vertex membrane, two
actuator sets, the paper's law as the design's controller (so the suite stays short)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import warp_shape as ws
from generated_shapes import shape
from warp_shape.controller.shard import available_cores
from warp_shape.io.report import design_markdown
from warp_shape.designer.codesign import (CodesignProblem, CodesignSettings, first_length, min_norm_direction,
                                         radial_modes, replayed_objectives)

CORES = available_cores()  # a design on a worker per core, as the command runs (the suite's own default is one process)
KW = dict(actuators=2, refine_rounds=0, control_settings=ws.ControlSettings(method="paper"))


@pytest.fixture(scope="module")
def targets():
    return [shape("egg", subdivisions=3), shape("tilted_ellipsoid", subdivisions=3)]


@pytest.fixture(scope="module")
def designs(targets):
    # each target's gradient and replay one job on the workers
    off = ws.design(ws.icosphere(2, 0.04), targets, codesign="off", workers=CORES, **KW)
    on = ws.design(ws.icosphere(2, 0.04), targets, workers=CORES, **KW)  # the default: rest+ipams
    return off, on


def test_radial_modes_are_orthonormal_smooth_and_scale_free():
    x = ws.icosphere(2, 0.04).vertices
    m = radial_modes(x, 4)
    assert m.shape == (24, len(x))  # the spherical harmonics of degrees 1..4: 3 + 5 + 7 + 9
    np.testing.assert_allclose(m @ m.T / len(x), np.eye(len(m)), atol=1e-10)
    np.testing.assert_allclose(m.sum(axis=1), 0.0, atol=1e-9)  # no uniform scale among them


def test_min_norm_direction_lowers_every_objective_to_first_order():
    rng = np.random.default_rng(1)
    g = rng.normal(size=(3, 8))
    d = min_norm_direction(g)
    assert np.all(g @ d >= d @ d - 1e-9)  # the min-norm point: every gradient has at least |d|^2 along it
    opposed = np.array([[1.0, 0.0], [-1.0, 0.0]])
    assert np.linalg.norm(min_norm_direction(opposed)) < 1e-9  # no common descent: no step


def test_codesign_is_never_worse_on_any_target_and_off_is_todays_design(designs, targets):
    off, on = designs
    rec = on.codesign
    assert rec["mode"] == "rest+ipams" and rec["kept"], rec["reason"]
    before, after = np.array(rec["before"]), np.array([r.objective for r in on.results])
    np.testing.assert_allclose(before, [r.objective for r in off.results], rtol=0, atol=0)  # the same placement
    assert np.all(after <= before), (before, after)  # per target
    assert np.all(after < before * 0.99), (before, after)  # and it pays on both
    # every accepted step lowered every replayed objective (within a round: each round starts from its
    # re-controlled sequences), and every round kept lowered no target's objective under the controller
    assert rec["steps"] and rec["recontrols"] and rec["recontrols"][0]["kept"]
    starts = [0] + [rc["step"] for rc in rec["recontrols"]]
    for a, b in zip(starts[:-1], starts[1:]):
        steps = np.array(([rec["before"]] if a == 0 else []) + rec["steps"][a:b])
        assert np.all(np.diff(steps, axis=0) <= 0), steps
    kept = [rc["objectives"] for rc in rec["recontrols"] if rc["kept"]]
    assert np.all(np.diff(np.array([rec["before"]] + kept), axis=0) <= 0)
    np.testing.assert_array_equal(kept[-1], after)
    # the rest shape stays within the initialisation's volume bound; sizes within their bounds
    bound = on.settings.volume_scale * min(t.volume() for t in targets)
    assert on.design.rest.volume() <= bound * (1 + 1e-9)
    lo, hi = CodesignSettings().size_bounds
    for ip, placed in zip(on.design.ipams, off.design.ipams):
        assert lo * placed.area <= ip.area <= hi * placed.area
    assert 0 < rec["max_displacement_m"] < 0.01
    assert off.codesign["mode"] == "off" and not off.codesign["kept"]
    report = design_markdown(on)
    assert "## Co-design" in report and "(kept)" in report and "Rest shape moved by at most" in report
    assert "| re-controlled |" in report  # each round's end in the step table
    assert "## Co-design" not in design_markdown(off)


def test_codesign_off_reproduces_the_design_bit_for_bit(designs, targets):
    off, _ = designs
    again = ws.design(ws.icosphere(2, 0.04), targets, codesign="off", workers=CORES, **KW)
    np.testing.assert_array_equal(again.design.rest.vertices, off.design.rest.vertices)
    np.testing.assert_array_equal(again.results[1].achieved.vertices, off.results[1].achieved.vertices)


def test_the_parameter_gradient_matches_finite_differences(designs):
    """The chain from vertex gradients to the modes and log sizes, against replayed objectives."""
    off, _ = designs
    results = [dataclasses.replace(r, settings=r.settings.replace(simulation=r.settings.simulation.replace(
        precision="float64"))) for r in off.results]  # the replays in float64, as the gradient
    problem = CodesignProblem(off.design, "rest+ipams", CodesignSettings(), volume_bound=np.inf)
    grads = problem.gradients(off.design, results, off.targets)
    def objective(design):
        return replayed_objectives(design, results, off.targets)
    rng = np.random.default_rng(0)
    direction = rng.normal(size=problem.size)
    direction /= np.abs(direction).max()
    eps = 1e-5
    up = objective(problem.design(eps * direction))
    down = objective(problem.design(-eps * direction))
    fd = (up - down) / (2 * eps)
    np.testing.assert_allclose(grads @ direction, fd, rtol=1e-4)


def test_the_gradient_at_the_volume_bound_is_that_of_the_design_held_at_it(designs):
    """A rest shape placed at the volume bound stays at it: the chained gradient is the scaled
    design's, against central differences of replayed objectives (both sides scaled to the bound)."""
    off, _ = designs
    results = [dataclasses.replace(r, settings=r.settings.replace(simulation=r.settings.simulation.replace(
        precision="float64"))) for r in off.results]
    problem = CodesignProblem(off.design, "rest", CodesignSettings(), volume_bound=off.design.rest.volume())
    assert problem.hold_volume
    grads = problem.gradients(off.design, results, off.targets)
    free = CodesignProblem(off.design, "rest", CodesignSettings(), volume_bound=np.inf).gradients(
        off.design, results, off.targets)
    direction = np.random.default_rng(2).normal(size=problem.size)
    direction /= np.abs(direction).max()
    eps = 1e-5
    up, down = problem.design(eps * direction), problem.design(-eps * direction)
    np.testing.assert_allclose([up.rest.volume(), down.rest.volume()], off.design.rest.volume(), rtol=1e-12)
    fd = (replayed_objectives(up, results, off.targets) - replayed_objectives(down, results, off.targets)) / (2 * eps)
    np.testing.assert_allclose(grads @ direction, fd, rtol=1e-4)
    # the unscaled gradient is not it: it misses by at least ten times the tolerance the scaled one meets
    assert np.abs(free @ direction - fd).max() > 10 * 1e-4 * np.abs(fd).max()


def test_first_length_halves_the_step_to_the_linear_models_zero():
    assert first_length(np.array([0.02, 0.01]), np.array([-0.01, -0.1])) == pytest.approx(0.05)
    assert first_length(np.array([0.02]), np.array([-0.001])) == 1.0  # at most the whole step
    assert first_length(np.array([0.02]), np.array([0.001])) == 1.0  # nothing falls: the whole step
    # at most the length the step before was accepted at
    assert first_length(np.array([0.02]), np.array([-0.001]), 0.25) == 0.25
    assert first_length(np.array([0.02, 0.01]), np.array([-0.01, -0.1]), 0.25) == pytest.approx(0.05)


def test_a_step_that_met_the_curvature_halves_the_next_steps_first_trial():
    """The next step's longest first trial: the accepted length, halved where a target realised less than
    ``SHRINK_BELOW`` of its first-order predicted decrease (a target predicted not to fall is not judged)."""
    from warp_shape.designer.codesign import SHRINK_BELOW, next_longest

    predicted = np.array([0.001, 0.002])
    assert next_longest(0.5, predicted, np.array([0.0006, 0.0009])) == 0.5  # 60 % and 45 % realised
    assert next_longest(0.5, predicted, np.array([0.0006, 0.0007])) == 0.25  # 35 % realised on one
    assert next_longest(1.0, predicted, predicted * (SHRINK_BELOW - 1e-9)) == 0.5
    assert next_longest(1.0, predicted, predicted * SHRINK_BELOW) == 1.0
    assert next_longest(1.0, np.array([0.001, -0.001]), np.array([0.0005, -0.01])) == 1.0  # the rise not judged


def _kw(off, targets):
    return dict(mode="rest", volume_bound=off.settings.volume_scale * min(t.volume() for t in targets),
                control_settings=KW["control_settings"], passive_ipams=off.passive_ipams,
                passive_cells=off.passive_cells)


def test_a_round_ends_after_a_step_that_lowered_no_objective_by_more_than_min_gain(designs, targets):
    """``min_gain``: a step's replayed gain (at most the fraction asked, here 90 %) ends its round, so
    of 3 steps allowed one is taken, and the record says why; the re-control still follows it, and no
    round follows (the objectives stopped falling: of 2 rounds allowed one runs, one re-control)."""
    import warp_shape.designer.codesign as cd

    off, _ = designs
    _, _, rec = cd.codesign(off.design, off.targets, off.results,
                            settings=CodesignSettings(steps=3, rounds=2, min_gain=0.9), **_kw(off, targets))
    assert len(rec.steps) == 1 and len(rec.recontrols) == 1
    assert "step 1: no target's objective fell by more than 90.0%" in rec.reason


def test_a_round_whose_re_control_and_held_sequence_are_worse_keeps_the_round_before(designs, targets,
                                                                                      monkeypatch):
    """Round 2's re-control and target 0's held sequence made worse: co-design returns round 1's
    design and results."""
    import warp_shape.designer.codesign as cd

    off, _ = designs
    kw = _kw(off, targets)
    one = cd.codesign(off.design, off.targets, off.results, settings=CodesignSettings(steps=1, rounds=1), **kw)
    calls, control_many, replay_result = [], cd.control_many, cd.replay_result

    def worse_second_time(*a, **k):
        out = control_many(*a, **k)
        calls.append(1)
        return out if len(calls) == 1 else [dataclasses.replace(out[0], objective=1.0)] + out[1:]

    monkeypatch.setattr(cd, "control_many", worse_second_time)
    monkeypatch.setattr(cd, "replay_result", lambda *a, **k: dataclasses.replace(
        replay_result(*a, **k), **(dict(objective=2.0) if len(calls) == 2 else {})))
    two = cd.codesign(off.design, off.targets, off.results, settings=CodesignSettings(steps=1, rounds=2), **kw)
    rec = two[2]
    assert len(calls) == 2 and rec.kept and [rc["kept"] for rc in rec.recontrols] == [True, False]
    assert rec.recontrols[1]["held"] == []
    assert "round 2: re-controlled, target 0 got worse" in rec.reason and "round 1's design is kept" in rec.reason
    np.testing.assert_array_equal(two[0].rest.vertices, one[0].rest.vertices)
    assert rec.after == one[2].after == [r.objective for r in two[1]]


def test_a_target_whose_re_control_is_worse_than_its_held_sequence_keeps_the_sequence(designs, targets,
                                                                                       monkeypatch):
    """Re-control made worse on target 0: its held sequence, replayed on the co-designed design, is
    its result (the replay's objective, history and frames), the round is kept, and the objective is
    the one the descent reached for it."""
    import warp_shape.designer.codesign as cd

    off, _ = designs
    control_many = cd.control_many
    monkeypatch.setattr(cd, "control_many", lambda *a, **k: [dataclasses.replace(r, objective=1.0) if j == 0 else r
                                                             for j, r in enumerate(control_many(*a, **k))])
    design, results, rec = cd.codesign(off.design, off.targets, off.results,
                                       settings=CodesignSettings(steps=1, rounds=1), **_kw(off, targets))
    assert rec.kept and rec.recontrols[0]["held"] == [0] and rec.recontrols[0]["kept"]
    r, placed = results[0], off.results[0]
    assert r.objective < placed.objective and r.design is design
    # the descent's replayed objective (its replays are float64, for its gradients; this one float32 as the run)
    assert r.objective == pytest.approx(rec.steps[-1][0], rel=1e-5)
    assert len(r.history["time"]) == len(placed.history["time"]) == len(r.frames)
    for k in ("time", "air_mol", "ipam0_pressure_pa", "cell0_jammed", "phase"):
        np.testing.assert_array_equal(r.history[k], placed.history[k])
    assert r.history["objective"][-1] == r.objective
    np.testing.assert_allclose(r.achieved.vertices, ws.replay(design, placed), rtol=0, atol=0)


def test_a_held_targets_next_round_starts_from_its_trial_replay_bit_for_bit(designs, targets):
    """At a round's end a target whose re-control is above its held sequence keeps the sequence, and the
    next round starts from that sequence's replay made already (its plan), not a new one: the same
    objectives and final shapes bit for bit as replaying every round-end result afresh; the other
    target's start replay is made in the same batch."""
    import warp_shape.designer.codesign as cd

    off, _ = designs
    replays = cd.replayed(off.design, off.results, targets)
    new = [dataclasses.replace(off.results[0], objective=1.0), off.results[1]]  # target 0's re-control worse
    out, held, starts = cd.round_end(off.design, new, off.results, targets, replays, "cpu", True)
    assert held == [0] and out[0].objective < 1.0 and out[1] is off.results[1]
    assert starts[1][0] is replays[1][0]  # the held target's plan is the one it had
    fresh = cd.replayed(off.design, out, targets)
    np.testing.assert_array_equal(starts[0], fresh[0])
    for a, b in zip(starts[1], fresh[1]):
        np.testing.assert_array_equal(a.final, b.final)
    assert cd.round_end(off.design, new, off.results, targets, replays, "cpu", False)[2] is None


def test_codesign_on_a_runs_workers_takes_the_steps_it_takes_in_one_process(designs, targets):
    """The targets' gradients and replays as one job each on the run's workers: the same steps, rest
    shape and IPAM sizes bit for bit (the re-control, sharded, within 1e-5)."""
    from warp_shape.controller.shard import worker_pool
    from warp_shape.designer.codesign import codesign

    off, _ = designs
    kw = dict(mode="rest+ipams", volume_bound=off.settings.volume_scale * min(t.volume() for t in targets),
              control_settings=KW["control_settings"], passive_ipams=off.passive_ipams,
              passive_cells=off.passive_cells, settings=CodesignSettings(steps=1, rounds=1))
    here = codesign(off.design, off.targets, off.results, **kw)
    with worker_pool(2) as pool:
        pool.start()
        there = codesign(off.design, off.targets, off.results, **kw)
        assert len(pool.job_seconds) >= 3  # the gradients, the replays before and of the trial
    a, b = here[2].as_dict(), there[2].as_dict()
    assert a["kept"] and b["kept"] and a["steps"] == b["steps"] and a["before"] == b["before"]
    np.testing.assert_array_equal(here[0].rest.vertices, there[0].rest.vertices)
    assert [ip.area for ip in here[0].ipams] == [ip.area for ip in there[0].ipams]
    np.testing.assert_allclose(a["after"], b["after"], rtol=0, atol=1e-5)


def test_bad_codesign_mode_is_named():
    with pytest.raises(ws.DesignError, match=r"codesign must be one of \['off', 'rest', 'rest\+ipams'\]"):
        ws.DesignSettings(codesign="shape")


def test_the_command_codesigns_and_saves_the_codesigned_rest_shape(tmp_path):
    from warp_shape.cli import main

    out, rrd = tmp_path / "out", tmp_path / "run.rrd"
    problem = ws.save_scene(ws.Scene(design=ws.Design(ws.icosphere(2, 0.04)), targets=[ws.target("oval")],
                                     target_names=["oval"],
                                     settings={"controller": {"method": "paper"},
                                               "designer": {"actuators": 1, "codesign": "off", "codesign_steps": 2,
                                                            "codesign_rounds": 1}}),
                            tmp_path / "problem.usda")
    assert main(["design", str(problem), "--placement", "paper", "--codesign", "rest", "--rerun", str(rrd),
                 "--out", str(out)]) == 0  # the flag over the scene's designer group
    report = (out / "report.md").read_text()
    assert "## Co-design" in report and "Mode: rest" in report
    scene = ws.load_scene(out / "design.usda")
    assert scene.settings["designer"]["codesign"] == "rest"
    rec = json.loads((out / "report.json").read_text())["codesign"]
    assert rec["kept"] and all(a <= b for a, b in zip(rec["after"], rec["before"]))
    assert len(rec["steps"]) <= 2 and len(rec["recontrols"]) == 1  # the scene's co-design settings
    # the saved rest shape is the co-designed one: within the volume bound, moved from the placed one
    assert scene.design.rest.volume() <= 0.8 * ws.target("oval").volume() * (1 + 1e-9)
    assert rec["max_displacement_m"] > 1e-4
    # the recording logs every step's replayed objective and the final one
    from warp_shape.io.recording_read import read_recording

    ents = read_recording(rrd)["entities"]
    logged = np.concatenate(ents["/design/codesign/oval"]["Scalars:scalars"])
    np.testing.assert_allclose(logged, [rec["before"][0]] + [row[0] for row in rec["steps"]])
    assert np.concatenate(ents["/design/codesign/oval/final"]["Scalars:scalars"])[0] == pytest.approx(rec["after"][0])
