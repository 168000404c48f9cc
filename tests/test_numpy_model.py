"""The NumPy (float64) implementation used by the benchmark agrees with the Warp simulator."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from conftest import Scenario, rel_err
from warp_shape.benchmarks.numpy_baseline import NumpyMembrane


@pytest.fixture(scope="module")
def scenario():
    return Scenario(precision="float64")


def test_forces_match_simulator(scenario):
    nm = NumpyMembrane.from_simulator(scenario.sim)
    assert rel_err(nm.forces(), scenario.sim.forces()) < 1e-12
    e_sim, e_np = scenario.sim.energy(), nm.energy()
    for key in ("spring", "bending", "gas", "ipam", "kinetic"):
        assert e_np[key] == pytest.approx(e_sim[key], rel=1e-11, abs=1e-15), key


@pytest.mark.parametrize("integrator,bending", [("rk4", "exact"), ("semi_implicit", "exact"), ("rk4", "paper")])
def test_trajectory_matches_simulator(integrator, bending):
    s = Scenario(precision="float64", bending=bending)
    src = s.sim
    sim = ws.Simulator(s.design, integrator=integrator, precision="float64", bending=bending, dt=2e-4, substeps=2)
    sim.positions, sim.velocities = src.positions, src.velocities
    sim.air_moles, sim.ipam_pressures = src.air_moles, src.ipam_pressures
    sim.positions = s.x_jam
    sim.jam(0)
    sim.positions = s.x
    nm = NumpyMembrane.from_simulator(sim)
    assert nm.h == pytest.approx(1e-4) and nm.edge_jammed.sum() > 0
    sim.step(10)  # 20 internal steps
    nm.step(20)
    scale = np.abs(sim.positions - s.x).max()
    assert scale > 1e-6  # it moved
    assert np.abs(nm.positions - sim.positions).max() < 1e-10 * max(1.0, np.abs(s.x).max())
    assert rel_err(nm.velocities, sim.velocities) < 1e-9


def test_own_jam_matches_simulator():
    s = Scenario(precision="float64")
    sim = ws.Simulator(s.design, precision="float64", dt=1e-4, substeps=1)
    nm = NumpyMembrane(s.design, h=1e-4)
    for target in (sim, nm):
        target.positions = s.x_jam
        target.jam(1)
        target.positions = s.x
        target.velocities = s.v
    nm.air_moles = sim.air_moles
    assert rel_err(nm.forces(), sim.forces()) < 1e-12
    sim.step(5)
    nm.step(5)
    assert np.abs(nm.positions - sim.positions).max() < 1e-12


def test_rejects_unknown_integrator(scenario):
    with pytest.raises(ws.DesignError, match="unknown integrator"):
        NumpyMembrane(scenario.design, integrator="leapfrog9")
