"""IPAM (eqs. 3-5) and jamming-cell behaviour."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from conftest import rel_err
import reference as ref


def _two_pole_design(stiffness=400.0, subdivisions=3):
    rest = ws.icosphere(subdivisions, 0.04)
    d = ws.Design(rest)
    c = rest.face_centroids()
    ends = []
    for axis in (2, 0):
        a, b = int(np.argmax(c[:, axis])), int(np.argmin(c[:, axis]))
        d.add_ipam(a, b, stiffness=stiffness)
        d.add_cell(np.flatnonzero(np.linalg.norm(c - c[a], axis=1) < 0.015))
        ends.append(a)
    return d, ends


def _centroid_distance(x, faces, a, b):
    return float(np.linalg.norm(x[faces[b]].mean(0) - x[faces[a]].mean(0)))


def test_ipam_natural_length_and_reported_force():
    d, _ = _two_pole_design()
    sim = ws.Simulator(d, precision="float64")
    rng = np.random.default_rng(0)
    sim.positions = d.rest.vertices * 1.03 + rng.normal(0, 2e-4, d.rest.vertices.shape)
    x, faces = sim.positions, d.rest.faces
    for P in ([0.0, 0.0], [50e3, -20e3], [250e3, 100e3]):
        sim.ipam_pressures = P
        for i, ip in enumerate(d.ipams):
            L = _centroid_distance(x, faces, ip.face_a, ip.face_b)
            Ln = ip.free_length + ip.area / ip.stiffness * P[i]
            assert ip.natural_length(P[i]) == pytest.approx(Ln, rel=1e-12)
            assert sim.ipam_lengths()[i] == pytest.approx(L, rel=1e-12)
            assert sim.ipam_forces()[i] == pytest.approx(ip.stiffness * (L - Ln), rel=1e-9, abs=1e-12)


def test_ipam_exerts_no_force_at_matching_pressure():
    d, _ = _two_pole_design()
    sim = ws.Simulator(d, precision="float64")
    # rest shape rigidly rotated and translated: every sub-spring is at its rest length
    th = 0.4
    Rm = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    sim.positions = d.rest.vertices @ Rm.T + [0.01, -0.02, 0.005]
    P = [ip.pressure_for_length(ip.rest_length) for ip in d.ipams]
    P = [p if p != 0 else 0.0 for p in P]
    sim.ipam_pressures = P
    assert np.abs(sim.ipam_forces()).max() < 1e-9
    assert np.abs(sim.forces("ipam")).max() < 1e-9
    # a different pressure does act, along the actuator
    sim.ipam_pressures = [P[0] + 50e3, P[1]]
    f = sim.forces("ipam")
    assert np.abs(f).max() > 1e-3
    assert sim.ipam_forces()[0] < 0  # longer natural length: the actuator pushes (compression)


def test_ipam_free_length_offsets_match_reference():
    d, _ = _two_pole_design()
    for ip in d.ipams:
        pairs, offsets = ref.ipam_pairs(d.rest.vertices, d.rest.faces, ip.face_a, ip.face_b)
        np.testing.assert_array_equal(ip.pairs, pairs)
        np.testing.assert_allclose(ip.offsets, offsets, atol=1e-15)


def test_ipam_pressure_moves_the_membrane():
    """Raising IPAM pressure lengthens the device along the actuator; lowering it shortens it."""
    d, _ = _two_pole_design(stiffness=200.0)
    lengths = {}
    for P in (-40e3, 0.0, 150e3):
        sim = ws.Simulator(d)
        sim.air_moles = sim.air_moles * 1.05
        sim.ipam_pressures = [P, 0.0]
        sim.step(300)
        lengths[P] = sim.ipam_lengths()[0]
    assert lengths[-40e3] < lengths[0.0] < lengths[150e3]


def _kappa(sim, d, ends):
    x, f = sim.positions, d.rest.faces
    r = np.linalg.norm(x[f].mean(axis=1), axis=1)
    return np.array([r[e] - r[d.cells[i].faces].mean() for i, e in enumerate(ends)])


def test_jam_resets_rest_values_and_stiffens_once():
    d, _ = _two_pole_design(subdivisions=2)
    sim = ws.Simulator(d, precision="float64")
    rng = np.random.default_rng(5)
    x1 = d.rest.vertices * 1.04 + rng.normal(0, 3e-4, d.rest.vertices.shape)
    sim.positions = x1
    sim.jam(0)
    edges = d.cell_edges(0)
    lengths, angles = sim.edge_state()
    rest_len = sim.state.rest_length.numpy()[0]
    rest_ang = sim.state.rest_angle.numpy()[0]
    np.testing.assert_allclose(rest_len[edges], lengths[edges], rtol=1e-12)
    np.testing.assert_allclose(rest_ang[edges], angles[edges], rtol=1e-12, atol=1e-14)
    other = np.setdiff1d(np.arange(len(rest_len)), edges)
    np.testing.assert_allclose(rest_len[other], sim.model.host.rest_length[other], rtol=1e-12)
    # jammed edges are at rest right after jamming: the cell's springs and hinges carry no force
    H = ref.hinges(d.rest.faces)
    mask = ref.cell_edge_mask(d.rest.faces, d.cells[0].faces)
    assert mask.sum() == len(edges)
    # jamming again somewhere else changes nothing (once, never re-frozen, never unjammed)
    sim.positions = x1 * 1.01
    before = sim.forces("spring")
    sim.jam(0)
    np.testing.assert_array_equal(sim.forces("spring"), before)
    assert sim.jammed.tolist() == [True, False]
    # stiffness x10 / x30: compare with the oracle, which stiffens by the factors
    k = ref.spring_stiffness(d.rest.vertices, d.rest.faces, H, 69e3, 2e-3)
    L = ref.edge_lengths(d.rest.vertices, H)
    th = ref.dihedral(d.rest.vertices, H)
    Lj, thj, kj, ktj, _ = ref.jam(x1, H, mask, L, th, k, 1e-4, 10.0, 30.0)
    x = sim.positions
    np.testing.assert_allclose(kj[mask], 10 * k[mask])
    assert rel_err(sim.forces("spring"), ref.spring_forces(x, np.zeros_like(x), H, Lj, kj, 0.0)) < 1e-9
    assert rel_err(sim.forces("bending"), ref.bending_forces_exact(x, H, thj, ktj)) < 1e-9


def test_edge_shared_by_two_cells_is_stiffened_once():
    rest = ws.icosphere(2, 0.04)
    d = ws.Design(rest)
    adj = rest.face_adjacency()
    d.add_cell([0])
    d.add_cell([int(adj[0, 0])])  # shares one edge with cell 0
    sim = ws.Simulator(d, precision="float64")
    rng = np.random.default_rng(2)
    x1 = rest.vertices * 1.02 + rng.normal(0, 2e-4, rest.vertices.shape)
    x2 = rest.vertices * 1.03 + rng.normal(0, 2e-4, rest.vertices.shape)
    sim.positions = x1
    sim.jam(0)
    sim.positions = x2
    sim.jam(1)
    shared = np.intersect1d(d.cell_edges(0), d.cell_edges(1))
    assert shared.size == 1
    jammed = sim.state.jammed.numpy()[0]
    assert jammed[shared[0]] == 1 and jammed.sum() == 5
    # the shared edge kept the length it had when the first cell jammed
    e = shared[0]
    a, b = sim.model.host.hinges[e, :2]
    assert sim.state.rest_length.numpy()[0, e] == pytest.approx(np.linalg.norm(x1[b] - x1[a]), rel=1e-12)


def test_jammed_cell_holds_its_curvature():
    """Two identical IPAM ends with cells; only one is jammed; adding air bends the free one more."""
    d, ends = _two_pole_design()
    sim = ws.Simulator(d)
    sim.air_moles = sim.air_moles * 1.05
    sim.step(300)
    k0 = _kappa(sim, d, ends)
    assert abs(k0[0] - k0[1]) < 0.05 * abs(k0[0])  # symmetric before jamming
    sim.jam(0)
    sim.air_moles = sim.air_moles * 1.10
    sim.step(300)
    change = np.abs(_kappa(sim, d, ends) - k0)
    assert change[1] > 1e-4
    assert change[0] < 0.5 * change[1], f"jammed {change[0]:.2e} m vs free {change[1]:.2e} m"
    assert sim.jam_times[0] == pytest.approx(0.3) and np.isnan(sim.jam_times[1])


def test_jamming_shrinks_the_stable_step():
    d, _ = _two_pole_design(subdivisions=2)
    sim = ws.Simulator(d)
    before = sim.stable_dt()
    sim.jam(0)
    sim.jam(1)
    ratio = before / sim.stable_dt()
    assert 2.0 < ratio < 4.0, ratio  # ~sqrt(10) for x10 stretch stiffness
    assert sim.substeps >= 2
