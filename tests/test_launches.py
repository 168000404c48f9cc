"""Model only what a scene requires: count the kernels one step launches."""

from __future__ import annotations

import numpy as np
from launch_counter import LaunchCounter

import warp_shape as ws


def _count_launches(sim, n=2):
    with LaunchCounter() as counter:
        sim.step(n)
    return counter.kernels


def test_plain_membrane_launches_no_ipam_bending_or_jamming():
    d = ws.Design(ws.icosphere(2, 0.04), ws.Material(bending_stiffness=0.0))
    sim = ws.Simulator(d, launch_mode="direct", substeps=1, dt=1e-4)
    counts = _count_launches(sim, 2)
    assert not any("ipam" in k or "bending" in k or "jam" in k for k in counts), counts
    # RK4: four force evaluations a step, each one fused hinge pass (springs, volume, dV/dx), then the
    # stage (which applies the pressure and starts the next evaluation); one init per step
    assert counts["eval_hinge_kernel"] == 8 and counts["rk4_stage_fused"] == 8
    assert counts["init_step_forces"] == 2
    assert not any("ipam" in k or "bending" in k for k in sim.step_kernels)


def test_each_family_launches_once_per_force_evaluation():
    rest = ws.icosphere(2, 0.04)
    d = ws.Design(rest)
    d.add_ipam(0, int(np.argmin(rest.face_centroids()[:, 2] - rest.face_centroids()[0, 2])))
    d.add_cell([5, 6])
    for integrator, evals in (("rk4", 4), ("semi_implicit", 1)):
        sim = ws.Simulator(d, integrator=integrator, launch_mode="direct", substeps=1, dt=1e-4)
        counts = _count_launches(sim, 1)
        # springs, bending, volume and dV/dx share one fused pass over the hinges
        for k in ("eval_hinge_bending_kernel", "eval_ipam_kernel"):
            assert counts[k] == evals, (integrator, k, counts)
        assert counts["init_step_forces"] == 1
        assert "eval_hinge_kernel" not in counts
        assert "jam_edges_kernel" not in counts  # jamming launches only when a cell jams


def test_graph_mode_replays_without_python_launches():
    sim = ws.Simulator(ws.Design(ws.icosphere(2, 0.04)))
    sim.step(1)  # plan built
    counts = _count_launches(sim, 5)
    assert not counts, counts  # the step is a replayed graph and the check a recorded launch
