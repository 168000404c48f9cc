"""Nothing NaN, nothing lost, nothing hangs: every failure a bad-input sweep found, each with its message.

A simulator that raises keeps its last good state (or refuses further steps with the same error);
an interrupt inside a step leaves a state whose positions, step count and time agree; inputs are
checked in the precision they are stored in; an output step that would need more internal steps
than ``max_substeps`` is refused naming the value behind it; API and scene-loader checks raise
warp_shape errors, never library tracebacks.
"""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws


def _sphere(subdivisions=1):
    return ws.icosphere(subdivisions, 0.04)


def _runaway(sim):
    v = np.zeros((sim.model.n_vertices, 3))
    v[0] = [1e5, 0, 0]  # crosses the device in one internal step
    return v


# --------------------------------------------------------------------------- last good state


def test_blowup_restores_the_last_good_state():
    """After a SimulationError the state is that after the last whole output step: finite, with the
    step count and time that belong to it; the simulator keeps working once the bad input is gone."""
    d = ws.Design(_sphere())
    clean = ws.Simulator(d)
    clean.step(2)
    sim = ws.Simulator(d)
    sim.step(2)
    x2, v2 = sim.positions, sim.velocities
    sim.velocities = _runaway(sim)
    with pytest.raises(ws.SimulationError, match=r"blew up at output step 3 .*ran away"):
        sim.step(3)
    assert sim.step_count == 2 and sim.time == pytest.approx(2 * sim.dt)
    np.testing.assert_array_equal(sim.positions, x2)  # the failed step left no trace in the positions
    assert sim.volume() == pytest.approx(d.rest.volume(), rel=0.05) and np.isfinite(sim.pressure())
    sim.velocities = v2  # the bad input taken back: the run continues as if it never happened
    sim.air_moles = sim.air_moles  # the old failure mode: "cannot convert float NaN to integer"
    sim.step(1)
    clean.step(1)
    np.testing.assert_allclose(sim.positions, clean.positions, atol=1e-9)
    assert sim.step_count == 3 and np.all(np.isfinite(sim.positions))


def test_state_corrupted_behind_the_api_refuses_every_further_step():
    """Where even the last good state is not finite, every further step repeats the clear error
    until positions and velocities are set through the API."""
    sim = ws.Simulator(ws.Design(_sphere()))
    sim.step(1)
    x = sim.state.x.numpy()
    x[0, 3, 1] = np.nan
    sim.state.x.assign(x)
    with pytest.raises(ws.SimulationError, match="positions became non-finite"):
        sim.step(1)
    for _ in range(2):
        with pytest.raises(ws.SimulationError, match="non-finite.*set positions and velocities to continue"):
            sim.step(1)
    assert sim.step_count == 1
    sim.positions = sim.design.rest.vertices
    sim.step(2)
    assert sim.step_count == 3 and np.all(np.isfinite(sim.positions))


def test_interrupt_inside_a_step_leaves_a_consistent_state(monkeypatch):
    """Ctrl-C in the middle of an output step's internal steps: that output step did not happen
    (positions, velocities, step_count and time those before it), so a rerun of it continues the
    same trajectory as a clean run. The old behaviour kept the internal steps run (13.4 mm off)."""
    d = ws.Design(_sphere())
    clean = ws.Simulator(d)
    clean.air_moles = clean.air_moles * 1.3
    clean.step(2)
    sim = ws.Simulator(d)
    sim.air_moles = sim.air_moles * 1.3
    sim.step(1)
    x1 = sim.positions
    run = sim.plan.run

    def interrupted(count):
        run(max(1, count // 2))  # half the internal steps of the output step, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(sim.plan, "run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sim.step(1)
    monkeypatch.setattr(sim.plan, "run", run)
    assert sim.step_count == 1 and sim.time == pytest.approx(sim.dt)
    np.testing.assert_array_equal(sim.positions, x1)
    sim.step(1)
    np.testing.assert_allclose(sim.positions, clean.positions, atol=1e-9)


def test_interrupt_keeps_the_whole_output_steps_already_taken(monkeypatch):
    """An interrupt in the third output step of ``step(5)`` keeps the two whole ones before it."""
    d = ws.Design(_sphere())
    sim = ws.Simulator(d)
    sim.air_moles = sim.air_moles * 1.3
    run, calls = sim.plan.run, []

    def interrupted(count):
        calls.append(count)
        if len(calls) == 3:
            raise KeyboardInterrupt
        run(count)

    monkeypatch.setattr(sim.plan, "run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sim.step(5)
    monkeypatch.setattr(sim.plan, "run", run)
    ref = ws.Simulator(d)
    ref.air_moles = ref.air_moles * 1.3
    ref.step(2)
    assert sim.step_count == 2
    np.testing.assert_array_equal(sim.positions, ref.positions)


# --------------------------------------------------------------------------- inputs in their storage precision


def test_positions_are_checked_in_the_precision_they_are_stored_in():
    """x 1e41 is finite in float64 but inf in float32: refused before it reaches the state."""
    d = ws.Design(_sphere())
    sim = ws.Simulator(d)
    with pytest.raises(ws.DesignError, match=r"positions up to .* do not fit in float32.*precision='float64'"):
        sim.positions = sim.positions * 1e41
    with pytest.raises(ws.DesignError, match="velocities up to .* do not fit in float32"):
        sim.velocities = np.full((d.rest.n_vertices, 3), 1e39)
    assert np.isfinite(sim.volume()) and sim.volume() == pytest.approx(d.rest.volume(), rel=1e-6)
    sim.step(1)
    assert np.all(np.isfinite(sim.positions))


def test_material_values_that_do_not_fit_the_precision_are_refused():
    d = ws.Design(_sphere(), ws.Material(youngs_modulus=1e42))
    with pytest.raises(ws.DesignError, match=r"youngs_modulus x thickness .* does not fit in float32"):
        ws.Simulator(d)
