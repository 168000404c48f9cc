"""The trade-off bench's building blocks: open-loop replay and the Pareto front."""

from __future__ import annotations

import numpy as np

import warp_shape as ws
from warp_shape.benchmarks.tradeoff import pareto_front, record_sequence, replay
from warp_shape.controller import control
from warp_shape.scenarios import cube_fig6_design


def test_replaying_the_recorded_sequence_reproduces_the_controlled_shape():
    design = cube_fig6_design(subdivisions=2)
    cube = ws.target("cube")
    result = control(design, cube, method="paper")
    seq = record_sequence(design, cube)
    assert seq.steps == result.control_steps + 1
    assert np.array_equal(seq.jam_step, result.jam_steps)
    x, wall, substeps = replay(design, seq)
    np.testing.assert_array_equal(x, result.achieved.vertices)  # same commands, same device: same shape
    # a different integrator follows the same sequence to a nearby but different shape
    y, _, _ = replay(design, seq, integrator="semi_implicit")
    d = np.linalg.norm(y - x, axis=1).max()
    assert 0 < d < 1e-3


def test_pareto_front():
    rows = [dict(wall_s=1.0, error_mm=1.0), dict(wall_s=2.0, error_mm=0.5), dict(wall_s=3.0, error_mm=0.7),
            dict(wall_s=0.5, error_mm=2.0), dict(wall_s=4.0, error_mm=0.1)]
    front = pareto_front(rows)
    assert [(r["wall_s"], r["error_mm"]) for r in front] == [(0.5, 2.0), (1.0, 1.0), (2.0, 0.5), (4.0, 0.1)]


def test_peer_bench_says_why_it_cannot_run_without_newton():
    import importlib.util

    from warp_shape.benchmarks.peer import bench_peer

    if importlib.util.find_spec("newton") is not None:
        return  # Newton present: the bench runs (measured, not asserted)
    rows = bench_peer(subdivisions=(2,))
    assert len(rows) == 1 and "not installed" in rows[0]["note"]
