"""States allocated by the model, a step from one state into another, and world copies on the device."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import warp_shape as ws
import warp_shape.model as model_module
import warp_shape.simulator as simulator_module
from warp_shape.integrators import make_solver
from warp_shape.model import copy_worlds


def test_host_model_is_built_once_per_simulator(monkeypatch):
    calls = []
    real = model_module.host_model

    def counted(design):
        calls.append(design)
        return real(design)

    monkeypatch.setattr(model_module, "host_model", counted)
    monkeypatch.setattr(simulator_module, "host_model", counted)
    d = ws.Design(ws.icosphere(1, 0.04))
    sim = ws.Simulator(d)
    assert len(calls) == 1
    h = sim.model.host
    assert h.rest_air == sim.air_moles and h.n_ipams == 0 and h.n_cells == 0
    assert h.gas_rt == sim.model.gas_rt and h.atmospheric_pressure == sim.model.atmospheric_pressure


def _device():
    rest = ws.icosphere(1, 0.04)
    d = ws.Design(rest)
    d.add_ipam(0, int(np.argmin(rest.face_centroids()[:, 2] - rest.face_centroids()[0, 2])))
    d.add_cell([3, 4, 5])
    return d


def _moving(integrator="rk4", worlds=2, **kw):
    """A simulator of two different worlds, moving (more air, an IPAM pressure, a cell jammed)."""
    sim = ws.Simulator(_device(), integrator=integrator, worlds=worlds, dt=2e-4, **kw)
    sim.air_moles = np.linspace(1.25, 1.1, worlds) * sim.air_moles
    sim.ipam_pressures = np.linspace(2e4, 6e4, worlds)[:, None]
    sim.step(3)
    sim.jam(0, world=worlds - 1)
    return sim


def _arrays(state):
    return [state.xv.numpy().copy(), state.edge.numpy().copy(), state.jammed.numpy().copy(),
            state.cell_jammed.copy(), state.cell_jam_time.copy()]


@pytest.mark.parametrize("integrator", ["rk4", "semi_implicit"])
def test_a_step_leaves_its_input_state_unchanged(integrator):
    sim = _moving(integrator)
    m, a = sim.model, sim.state
    b = m.state(sim.worlds)  # fresh, at rest: the step gives it a's jam fields
    before = _arrays(a)
    solver = make_solver(integrator, m, sim.worlds)
    solver.step(a, b, sim.control, sim.internal_dt)
    for old, new in zip(before, _arrays(a)):
        assert old.tobytes() == new.tobytes()  # bit for bit
    assert b.shares_jam(a)
    assert not np.array_equal(b.xv.numpy(), before[0])  # the step went into b
    # a sequence into fresh states (what a recorded tape replays) keeps every state it passed through
    kept = b.xv.numpy().copy()
    c = m.state(sim.worlds)
    solver.step(b, c, sim.control, sim.internal_dt)
    assert b.xv.numpy().tobytes() == kept.tobytes() and a.xv.numpy().tobytes() == before[0].tobytes()
    assert not np.array_equal(c.xv.numpy(), kept)


@pytest.mark.parametrize("integrator", ["rk4", "semi_implicit"])
def test_steps_between_two_states_reproduce_the_step_in_place(integrator):
    """Stepping a -> b -> a ... (what the Simulator does) gives, bit for bit, what stepping one state
    in place gives (the arrangement before states were split)."""
    sim = _moving(integrator)
    m, h = sim.model, sim.internal_dt
    solver = make_solver(integrator, m, sim.worlds)
    in_place = m.state(sim.worlds, jam_from=sim.state)
    wp.copy(in_place.xv, sim.state.xv)
    for _ in range(5):
        solver.step(in_place, in_place, sim.control, h)
    pair = (m.state(sim.worlds, jam_from=sim.state), m.state(sim.worlds, jam_from=sim.state))
    wp.copy(pair[0].xv, sim.state.xv)
    for k in range(5):
        solver.step(pair[k % 2], pair[1 - k % 2], sim.control, h)
    assert pair[1].xv.numpy().tobytes() == in_place.xv.numpy().tobytes()
    # the Simulator's own two states, through its captured step plan, against its model stepped in place
    fresh = ws.Simulator(_device(), integrator=integrator, worlds=2, dt=h, substeps=1)
    fresh.air_moles, fresh.ipam_pressures = sim.air_moles, sim.ipam_pressures
    ref = fresh.model.state(2, jam_from=fresh.state)
    wp.copy(ref.xv, fresh.state.xv)
    fresh.step(5)
    solver = make_solver(integrator, fresh.model, 2)
    for _ in range(5):
        solver.step(ref, ref, fresh.control, h)
    assert fresh.plan.parity == 1 and fresh.state.xv.numpy().tobytes() == ref.xv.numpy().tobytes()


def _host_copy(dst, sources):
    """The host copy the controller used before world copies moved to the device: one (simulator,
    world) per world of ``dst``, through NumPy and the Simulator's setters."""
    rows = []
    for sim, w in sources:
        st = sim.state
        rows.append(dict(xv=st.xv.numpy()[:, w], edge=st.edge.numpy()[:, w], jam=st.jammed.numpy()[w],
                         cells=st.cell_jammed[w], times=st.cell_jam_time[w], air=np.atleast_1d(sim.air_moles)[w],
                         p=np.asarray(sim.ipam_pressures).reshape(sim.worlds, -1)[w]))
    st = dst.state
    st.edge.assign(np.stack([r["edge"] for r in rows], axis=1))
    st.jammed.assign(np.stack([r["jam"] for r in rows]))
    st.cell_jammed[:] = np.stack([r["cells"] for r in rows])
    st.cell_jam_time[:] = np.stack([r["times"] for r in rows])
    xv = np.stack([r["xv"] for r in rows], axis=1)
    dst.positions, dst.velocities = xv[0], xv[1]
    dst.air_moles = np.array([r["air"] for r in rows])
    dst.ipam_pressures = np.stack([r["p"] for r in rows])


def _everything(sim):
    st = sim.state
    return [st.xv.numpy(), st.edge.numpy(), st.jammed.numpy(), st.cell_jammed, st.cell_jam_time,
            sim.control.air.numpy(), sim.control.ipam_pressure.numpy()]


def test_device_world_copy_equals_the_host_copy_bit_for_bit():
    two, one = _moving(worlds=2), _moving(worlds=1)
    one.step(2)
    sources = [(two, 1), (two, 0), (one, 0), (two, 1)]  # a world copied twice, from two simulators
    host = ws.Simulator(_device(), worlds=4, dt=2e-4)
    _host_copy(host, sources)
    snaps = {id(two): two.snapshot(), id(one): one.snapshot()}
    two.step(1)  # a snapshot is a copy: what the source does next does not reach it
    device = ws.Simulator(_device(), worlds=4, dt=2e-4)
    device.load_worlds([snaps[id(sim)][w] for sim, w in sources])
    for a, b in zip(_everything(host), _everything(device)):
        assert a.tobytes() == b.tobytes()
    assert device.jammed[:, 0].tolist() == [True, False, True, True]  # the jam flags followed their worlds
    host.step(3)
    device.step(3)
    assert host.substeps == device.substeps
    assert host.state.xv.numpy().tobytes() == device.state.xv.numpy().tobytes()


def test_world_copies_refuse_what_does_not_fit():
    sim = _moving()
    other = sim.model.state(2)
    with pytest.raises(ws.DesignError, match="distinct destination"):
        copy_worlds(sim.state, sim.control, [0, 1], other, sim.model.control(2), [1, 1], sim.device)
    with pytest.raises(ws.DesignError, match="out of range"):
        copy_worlds(sim.state, sim.control, [2], other, sim.model.control(2), [0], sim.device)
    with pytest.raises(ws.DesignError, match="one world per world"):
        sim.load_worlds(sim.snapshot()[:1])
    for bigger in (ws.Simulator(ws.Design(ws.icosphere(2, 0.04)), worlds=2),
                   ws.Simulator(_device(), worlds=2, precision="float64")):
        before = bigger.state.xv.numpy().copy()
        with pytest.raises(ws.DesignError, match="same design and precision"):
            bigger.load_worlds(sim.snapshot())
        assert np.array_equal(bigger.state.xv.numpy(), before)
