"""The CUDA paths against the CPU: batched worlds, the captured step graph, blow-up reports, radial
sampling and the controller (the force families are compared per term in test_forces.py, the
integrators in test_integrators.py::test_cuda_matches_cpu).

These run where a CUDA device is present. ``WARP_SHAPE_CUDA_TEST_DEVICE=cpu`` runs them on the CPU
against the CPU, a dry run of the tests themselves (``scripts/gpu_check.sh --device cpu`` does that).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import warp as wp
from launch_counter import LaunchCounter

import warp_shape as ws
from warp_shape.sampling import RadialSampler, check_star_shaped
from warp_shape.simulation_settings import SimulationSettings

DEVICE = os.environ.get("WARP_SHAPE_CUDA_TEST_DEVICE") or ("cuda:0" if wp.is_cuda_available() else None)
ON_CUDA = DEVICE is not None and DEVICE.startswith("cuda")

pytestmark = [pytest.mark.cuda,
              pytest.mark.skipif(DEVICE is None, reason="needs a CUDA device "
                                 "(WARP_SHAPE_CUDA_TEST_DEVICE=cpu runs these tests on the CPU)")]


def _design(subdivisions=2):
    """Every force family: bending, an IPAM with damping, a jamming cell."""
    rest = ws.icosphere(subdivisions, 0.04)
    d = ws.Design(rest, ws.Material(bending_stiffness=2e-4, spring_damping=0.01, viscous_damping=0.03))
    c = rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])), damping=0.003)
    d.add_cell(np.flatnonzero(np.linalg.norm(c - c[int(np.argmax(c[:, 0]))], axis=1) < 0.015))
    return d


def _perturbed(d, seed=1):
    rng = np.random.default_rng(seed)
    return d.rest.vertices * 1.01 + rng.normal(0, 3e-4, d.rest.vertices.shape)


def _prepared(d, device, worlds=1, airs=(1.04,), pressures=(15e3,), **kwargs):
    """A simulator of ``d`` on ``device``: perturbed, inflated per world, IPAM pressures per world."""
    sim = ws.Simulator(d, device=device, precision=kwargs.pop("precision", "float64"), worlds=worlds, **kwargs)
    sim.positions = _perturbed(d)
    air = sim.air_moles * np.asarray(airs) if worlds > 1 else sim.air_moles * airs[0]
    sim.air_moles = air
    sim.ipam_pressures = np.asarray(pressures)[:, None] if worlds > 1 else [pressures[0]]
    return sim


def _run(sim, jam_after=8, steps=8):
    sim.step(jam_after)
    sim.jam(0)
    sim.step(steps)
    return np.asarray(sim.positions)


def test_batch_on_device_equals_single_runs_and_the_cpu():
    d = _design()
    airs, pressures = (1.0, 1.03, 1.06), (0.0, 10e3, 20e3)
    batch = _run(_prepared(d, DEVICE, worlds=3, airs=airs, pressures=pressures, substeps=4))
    cpu = _run(_prepared(d, "cpu", worlds=3, airs=airs, pressures=pressures, substeps=4))
    np.testing.assert_allclose(batch, cpu, rtol=0, atol=1e-10)
    assert np.abs(batch[2] - batch[0]).max() > 1e-4, "the worlds must differ for the comparison to mean anything"
    for w in range(3):
        one = _run(_prepared(d, DEVICE, airs=(airs[w],), pressures=(pressures[w],), substeps=4))
        np.testing.assert_allclose(batch[w], one, rtol=0, atol=1e-10)


@pytest.mark.parametrize("integrator", ["rk4", "semi_implicit"])
def test_captured_graph_replays_the_direct_launches(integrator):
    d = _design()
    graph = _prepared(d, DEVICE, integrator=integrator, launch_mode="graph", substeps=3)
    direct = _prepared(d, DEVICE, integrator=integrator, launch_mode="direct", substeps=3)
    graph.step(1)
    assert graph.plan.kind == "graph", graph.plan.kind  # captured (Warp captures on CPU too)
    with LaunchCounter() as counter:
        graph.step(5)
    assert not counter.kernels, counter.kernels  # replays only: no kernel launched from Python per step
    direct.step(6)
    np.testing.assert_allclose(graph.positions, direct.positions, rtol=0, atol=1e-10)
    assert np.abs(graph.positions - _perturbed(d)).max() > 1e-5, "the state must move"


def test_float32_on_device_tracks_float64():
    d = _design()
    x32 = _run(_prepared(d, DEVICE, precision="float32"))
    x64 = _run(_prepared(d, DEVICE, precision="float64"))
    assert np.abs(x32 - x64).max() < 1e-6  # m, on a 4 cm membrane


def test_blowup_on_device_names_the_step():
    # fixed substeps: automatic ones would take the step again from the last good state, which holds no NaN
    sim = _prepared(_design(), DEVICE, worlds=2, airs=(1.0, 1.02), pressures=(0.0, 5e3), substeps=100)
    assert sim.blowup_watch.deferred == ON_CUDA  # on a GPU the codes are noted on the device
    sim.step(3)
    x = sim.state.x.numpy()
    x[1, 7, 2] = np.nan
    sim.state.x.assign(x)
    with pytest.raises(ws.SimulationError, match=r"output step 4 .*world 1\).*non-finite") as info:
        sim.step(4)
    assert info.value.step == 4 and info.value.world == 1


def test_radial_sampling_on_device_matches_the_cpu():
    targets = [ws.target(n) for n in ("oval", "heart", "cube")]
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(3, 500, 3)) * 0.01
    world_targets = [0, 1, 2]
    on_device = RadialSampler(targets, device=DEVICE).sample_worlds(pts, world_targets)
    on_cpu = RadialSampler(targets, device="cpu").sample_worlds(pts, world_targets)
    np.testing.assert_allclose(on_device, on_cpu, rtol=0, atol=1e-6)  # m: float32 BVHs, float64 refinement
    # device arrays in and out (the controller's path): radii agree with the hits
    sampler = RadialSampler(targets, device=DEVICE, check=False)
    points = wp.array(pts.astype(np.float32), dtype=wp.vec3, device=DEVICE)
    hits, radii, faces = sampler.launch(points, sampler.mesh_ids(world_targets))
    assert (faces.numpy() >= 0).all()
    np.testing.assert_allclose(radii.numpy(), np.linalg.norm(on_cpu, axis=2), rtol=1e-5)
    assert check_star_shaped(targets[2], device=DEVICE)


def test_star_check_on_device_rejects_a_shape_not_star_shaped():
    rest = ws.icosphere(2, 0.04)
    v = rest.vertices.copy()
    v[:, 0] -= 0.05  # the origin now lies outside the sphere
    with pytest.raises(ws.ShapeError):
        check_star_shaped(ws.TriMesh(v, rest.faces), device=DEVICE)


def test_controller_on_device_matches_the_cpu():
    design = ws.Design(ws.icosphere(2, 0.035))
    c = design.rest.face_centroids()
    design.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])))
    sim_settings = SimulationSettings(precision="float64")
    runs = [ws.control(design, ws.target("oval"), device=dev, max_steps=40, simulation=sim_settings)
            for dev in (DEVICE, "cpu")]
    a, b = runs
    assert len(a.history["volume_m3"]) == len(b.history["volume_m3"])
    np.testing.assert_allclose(a.history["volume_m3"], b.history["volume_m3"], rtol=1e-7)
    np.testing.assert_allclose(a.ipam_pressures, b.ipam_pressures, rtol=1e-6, atol=1e-3)
    assert abs(a.pcc - b.pcc) < 1e-6 and a.pcc > 0.5
