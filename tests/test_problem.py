"""A design run's problem is built once (``controller.problem``): one radial sampler per run, each
target checked once; placements return decisions and leave the run as it was."""

from __future__ import annotations

import copy
import pickle
from types import SimpleNamespace

import numpy as np

import warp_shape as ws
import warp_shape.controller.checks as checks
import warp_shape.sampling as sampling
from warp_shape.controller import ControlSettings
from warp_shape.controller.problem import SAMPLERS, Problem
from warp_shape.designer.initialize import initial_rest_shape
from warp_shape.designer.loop import apply_decision
from warp_shape.designer.passive import PassiveSets
from warp_shape.designer.placement import Decision, PaperPlacement, PlacementContext, planned_cells
from warp_shape.designer.rounds import DesignRun
from warp_shape.designer.design_settings import DesignSettings


def _count(monkeypatch):
    counts = dict(samplers=0, star_checks=0, rest_checks=0)
    init, star, rest = sampling.RadialSampler.__init__, sampling.check_star_shaped, checks.check_targets_against_rest

    def counted_init(self, *a, **k):
        counts["samplers"] += 1
        return init(self, *a, **k)

    def counted_star(*a, **k):
        counts["star_checks"] += 1
        return star(*a, **k)

    def counted_rest(rest_shape, targets, *a, **k):
        counts["rest_checks"] += len(targets)
        return rest(rest_shape, targets, *a, **k)

    monkeypatch.setattr(sampling.RadialSampler, "__init__", counted_init)
    monkeypatch.setattr(sampling, "check_star_shaped", counted_star)
    monkeypatch.setattr(checks, "check_targets_against_rest", counted_rest)
    return counts


def test_a_design_run_builds_its_sampler_once_and_checks_each_target_once(monkeypatch):
    """A greedy round controls every target, then every candidate world (K x T, each target K times),
    and the last round every target again: before the problem value such a run built a sampler per
    batch and checked every world's target in each (with the inverse controller, two rounds: 8
    samplers, 28 star checks); now one sampler, one star check and one check against the rest shape
    per target."""
    counts = _count(monkeypatch)
    r = ws.design(ws.icosphere(1, 0.035), [ws.target("oval"), ws.target("heart")], actuators=1, placement="greedy",
                  candidates=2, min_gain=0.0, codesign="off", workers=1,
                  control_settings=ControlSettings(method="paper", max_steps=20, max_settle_steps=5, workers=1))
    assert len(r.rounds) == 2 and len(r.placement["rounds"][0]["candidates"]) == 2  # K x T candidate worlds ran
    assert counts == dict(samplers=1, star_checks=2, rest_checks=2)


def test_a_problems_worlds_sample_as_a_sampler_of_those_targets_alone():
    targets = [ws.target("oval").scaled(0.9), ws.target("heart")]
    problem = Problem(targets, ["oval", "heart"])
    view = problem.take([1, 0, 1])
    assert view.names == ["heart", "oval", "heart"] and view[0] is problem.all_targets[1]
    alone = sampling.RadialSampler([problem.all_targets[1], problem.all_targets[0], problem.all_targets[1]],
                                   check=False)
    assert view.sampler.max_t == alone.max_t  # the ray length (and the float64 refinement) of those targets
    x = np.random.default_rng(1).normal(size=(3, 40, 3)) * 0.01
    assert np.array_equal(view.sampler.sample_worlds(x), alone.sample_worlds(x))
    np.testing.assert_array_equal(view.volumes, [problem.all_targets[k].volume() for k in (1, 0, 1)])
    assert problem.take([0]).sampler.max_t < problem.sampler.max_t  # the oval alone: its own ray length
    # sent to a worker, a problem's sampler is built once for every job of the run, without a second star check
    SAMPLERS.clear()
    jobs = [pickle.loads(pickle.dumps(problem.take([j]))) for j in (0, 1, 1)]
    assert jobs[0].sampler.n_targets == 1 and len(SAMPLERS) == 1
    assert jobs[1].full_sampler() is jobs[2].full_sampler()


def _run():
    problem = Problem([ws.target("oval"), ws.target("heart")], ["oval", "heart"])
    rest = initial_rest_shape(ws.icosphere(1, 0.035), problem, 0.8)
    settings = DesignSettings(placement="paper")
    ctx = PlacementContext(sampler=problem.sampler, target_volumes=problem.volumes,
                           rest_centroids=rest.face_centroids(), settings=settings, actuators=2)
    run = DesignRun(current=ws.Design(rest), problem=problem, ctx=ctx, settings=settings,
                    control_settings=ControlSettings(), device="cpu", passive_sets=PassiveSets(2),
                    info=dict(rounds=[]))
    # each target reached as the rest shape inflated unevenly: the paper's rule has errors to rank
    shapes = [rest.copy_with(rest.vertices * (1.0 + 0.3 * np.abs(rest.vertices[:, [k]]) / 0.035)) for k in (0, 2)]
    return run, [SimpleNamespace(achieved=s) for s in shapes]


def _state(run):
    d = run.current
    return (d.n_ipams, d.n_cells, [(ip.face_a, ip.face_b) for ip in d.ipams], d.face_cell().tolist(),
            run.passive_sets.passive_ipams(), run.passive_sets.passive_cells(), copy.deepcopy(run.info),
            list(run.added), len(run.designs), len(run.rounds), run.final, run.round_control)


def test_a_placement_returns_a_decision_and_leaves_the_run_unchanged():
    run, results = _run()
    before = _state(run)
    decision = PaperPlacement().place(run, results, 0, run.control_settings)
    assert isinstance(decision, Decision) and _state(run) == before  # nothing of the run changed
    a, b = decision.ends
    assert decision.record["face_a"] == a and decision.record["face_b"] == b and decision.record["round"] == 0
    cells = planned_cells(run.current, a, b, run.ctx)
    assert cells == [0, 1]
    # the design loop applies it: the IPAM between those faces and a cell around each end
    assert apply_decision(run, decision) is decision.record
    assert [(ip.face_a, ip.face_b) for ip in run.current.ipams] == [(a, b)] and run.current.n_cells == 2
    assert run.current.face_cell()[a] == 0 and run.current.face_cell()[b] == 1
