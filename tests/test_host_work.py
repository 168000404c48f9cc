"""Host work batched over worlds: the stable-step Lanczos bound of every world in one pass, radial
sampling's float64 refinement and the fit metrics of every world at once, each with the values of
the one-world code (bit for bit); the control period's host / device breakdown of ``bench control``."""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from warp_shape import sampling
from warp_shape.objectives import radial
from warp_shape import stability as st
from warp_shape.errors import ShapeError
from warp_shape.scenarios import cube_fig6_design
from warp_shape.targets import target


def _differing_state(worlds: int, seed: int = 0):
    """A 162-vertex Fig. 6 simulator of ``worlds`` worlds and per world different positions and jams."""
    d = cube_fig6_design(subdivisions=2)
    sim = ws.Simulator(d, worlds=worlds)
    rng = np.random.default_rng(seed)
    x = sim.state.x.numpy().astype(np.float64)
    x = x * (1 + 0.05 * rng.standard_normal((worlds, 1, 1))) + 1e-4 * rng.standard_normal(x.shape)
    jam = rng.random(sim.state.jammed.numpy().shape) < 0.3
    return sim.model, x, jam, sim.state.rest_length.numpy().astype(np.float64)


def test_batched_lanczos_bound_equals_one_run_per_world():
    """elastic_omega2_bound runs every world together; each world's bound is the one its own Lanczos
    run gives, bit for bit, also where the worlds are split into several batches."""
    m, x, jam, rest = _differing_state(5)
    k_edge, kt = st.jammed_stiffness(m, jam)
    single = np.array([st.LANCZOS_SAFETY * st.lanczos_upper_bound(
        st.ElasticOperator(m, x[w], k_edge[w], rest[w], kt[w]), 3 * m.n_vertices) for w in range(5)])
    assert len(set(single.tolist())) == 5  # the worlds differ
    np.testing.assert_array_equal(st.elastic_omega2_bound(m, jam, x, rest), single)
    old = st.LANCZOS_BATCH
    try:
        st.LANCZOS_BATCH = 2
        np.testing.assert_array_equal(st.elastic_omega2_bound(m, jam, x, rest), single)
    finally:
        st.LANCZOS_BATCH = old


def test_batched_lanczos_keeps_a_world_whose_krylov_space_closes_early():
    """A world whose operator has two distinct eigenvalues closes after two steps: it keeps its 2 x 2
    tridiagonal matrix (the exact largest eigenvalue) while the other world runs on."""
    n = 40
    lam = np.linspace(1.0, 5.0, n)
    diag = [np.where(np.arange(n) < n // 2, 1.0, 3.0), lam]

    class Diagonal:
        def __call__(self, u):
            return u * np.stack(diag)

    out = st.lanczos_upper_bounds(Diagonal(), 2, n, steps=12)
    one = [st.lanczos_upper_bound(lambda u, k=k: u * diag[k], n, 12) for k in range(2)]
    np.testing.assert_array_equal(out, one)
    assert out[0] == pytest.approx(3.0, rel=1e-12)
    assert out[1] >= 5.0 * (1 - 1e-9)


def test_sampling_and_fit_of_many_worlds_equal_one_world_at_a_time():
    """sample_worlds refines the hits of every world at once, fit_metrics reduces every world at once:
    both equal the single-world sampling and metrics bit for bit (worlds on different targets)."""
    targets = [target(n) for n in ("cube", "oval", "heart")]
    sampler = sampling.RadialSampler(targets)
    rest = ws.icosphere(2, 0.04)
    rng = np.random.default_rng(2)
    W = 6
    pts = rest.vertices[None] * (1 + 0.1 * rng.standard_normal((W, 1, 1))) + 1e-3 * rng.standard_normal((W, 162, 3))
    wt = np.arange(W) % 3
    hits = sampler.sample_worlds(pts, wt)
    for w in range(W):
        np.testing.assert_array_equal(hits[w], sampler.sample(pts[w], int(wt[w])))
    r, R = np.linalg.norm(pts, axis=2), np.linalg.norm(hits, axis=2)
    weights = sampling.vertex_area_shares(hits, rest.faces)
    vols = np.array([targets[k].volume() for k in wt])
    fit = radial.fit_metrics(r, R, vols, weights)
    for w in range(W):
        assert fit["objective"][w] == radial.fit_objective(r[w], R[w], vols[w], weights[w])
        assert fit["pcc"][w] == sampling.pcc(r[w], R[w])
        assert fit["mare"][w] == sampling.mare(r[w], R[w])
        assert fit["mpre"][w] == sampling.mpre(r[w], R[w])
    flat = radial.fit_metrics(np.ones((2, 5)), np.full((2, 5), 1.1), np.ones(2), np.ones((2, 5)))
    np.testing.assert_array_equal(flat["pcc"], [0.0, 0.0])  # no spread: no shape to correlate


def test_fit_metrics_name_bad_inputs():
    r = np.ones((2, 4))
    with pytest.raises(ShapeError, match=r"r\[1, 2\] is not finite"):
        bad = r.copy()
        bad[1, 2] = np.nan
        radial.fit_metrics(bad, r, np.ones(2), r)
    with pytest.raises(ShapeError, match="one positive target volume per world"):
        radial.fit_metrics(r, r, np.ones(3), r)
    with pytest.raises(ShapeError, match=r"sampled radius R\[0, 0\] is not positive"):
        radial.fit_metrics(r, -r, np.ones(2), r)
    with pytest.raises(ShapeError, match="same shape"):
        radial.fit_metrics(r, np.ones((2, 3)), np.ones(2), r)


def test_control_breakdown_splits_a_period_into_device_and_host():
    """bench control's breakdown: the phases it times add up to the host share, the step kernels to
    the rest of the period."""
    from warp_shape.benchmarks.control import BREAKDOWN_COLUMNS, control_breakdown

    row = control_breakdown(worlds=3, periods=2, subdivisions=2)
    assert list(row) == BREAKDOWN_COLUMNS
    assert row["worlds"] == 3 and row["vertices"] == 162 and row["periods"] == 2
    assert row["device_ms"] > 0 and row["host_ms"] > 0
    assert row["period_ms"] == pytest.approx(row["device_ms"] + row["host_ms"], abs=0.02)
    parts = row["observe_ms"] + row["stable_step_ms"] + row["law_ms"] + row["record_ms"] + row["other_host_ms"]
    assert row["device_ms"] == pytest.approx(row["step_kernels_ms"] + row["ray_kernels_ms"], abs=0.02)
    assert parts == pytest.approx(row["host_ms"], abs=0.05)
    assert 0 < row["host_share"] < 1


def test_pressure_rows_of_many_worlds_equal_one_world_at_a_time():
    """The stable step's pressure terms (Gershgorin rows, gas eigenvalue) of every world at once equal
    each world's own, bit for bit."""
    from warp_shape.physics.pressure import pressure_rows_np

    m, x, _, _ = _differing_state(4)
    air = m.host.rest_air * np.array([0.9, 1.0, 1.2, 1.5])
    inv_m = 1.0 / m.host.mass
    press, gas = pressure_rows_np(x, m.host.faces, air, m.gas_rt, m.atmospheric_pressure, inv_m)
    for w in range(4):
        p1, g1 = pressure_rows_np(x[w:w + 1], m.host.faces, air[w:w + 1], m.gas_rt, m.atmospheric_pressure, inv_m)
        np.testing.assert_array_equal(press[w], p1[0])
        assert gas[w] == g1[0]


def test_a_jam_re_estimates_the_elastic_bound_of_the_jammed_world_only(monkeypatch):
    """After a jam in one world only that world's Lanczos bound is run again, and it is the bound a
    full estimate gives that world; the other worlds keep theirs until positions are set."""
    import warp_shape.simulator as simulator

    d = cube_fig6_design(subdivisions=2)
    sim = ws.Simulator(d, worlds=3)
    rng = np.random.default_rng(4)
    x = np.asarray(sim.positions, dtype=np.float64)
    sim.positions = x * (1 + 0.02 * rng.standard_normal((3, 1, 1)))
    sim.step(2)
    calls = []
    original = simulator.elastic_omega2_bound
    monkeypatch.setattr(simulator, "elastic_omega2_bound",
                        lambda m, jam, *a, **k: calls.append(jam.shape[0]) or original(m, jam, *a, **k))
    sim.stable_dt()
    assert calls == []  # cached
    sim.jam(0, world=1)
    sim.stable_dt()
    assert calls == [1]
    st_ = sim.state
    full = original(sim.model, st_.jammed.numpy().astype(bool), st_.x.numpy().astype(np.float64),
                    st_.rest_length.numpy().astype(np.float64))
    assert sim._elastic_cache[2][1] == full[1]
    from warp_shape.stability import jam_rows, stable_dt_estimate

    jammed = st_.jammed.numpy().astype(bool)
    for cached, fresh in zip(sim._elastic_cache[3], jam_rows(sim.model, jammed)):  # jam rows: the same, bit for bit
        np.testing.assert_array_equal(cached, fresh)
    assert not np.array_equal(sim._elastic_cache[3][0][1], sim._elastic_cache[3][0][0])  # world 1's rows moved
    uncached = stable_dt_estimate(sim.model, type(sim.solver), jammed, sim.control.air.numpy(),
                                  st_.x.numpy().astype(np.float64), st_.rest_length.numpy().astype(np.float64),
                                  elastic_bound=sim._elastic_cache[2])
    assert sim.stable_dt() == pytest.approx(float(uncached.min()), rel=1e-12)  # the device pressure terms: to rounding
    sim.positions = np.asarray(sim.positions)
    sim.stable_dt()
    assert calls == [1, 3]  # set positions: every world again


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_the_stable_steps_pressure_terms_on_the_device_are_the_host_ones(precision):
    """``pressure_rows`` (one kernel launch) gives ``pressure_rows_np``'s rows and gas eigenvalue to
    rounding, for every world and for the first worlds alone, in either precision."""
    from warp_shape.physics.pressure import pressure_rows, pressure_rows_np

    sim = ws.Simulator(cube_fig6_design(subdivisions=2), worlds=3, settings=ws.SimulationSettings(precision=precision))
    rng = np.random.default_rng(7)
    sim.positions = np.asarray(sim.positions) * (1 + 0.03 * rng.standard_normal((3, 1, 1)))
    sim.air_moles = sim.air_moles * np.array([1.0, 1.2, 0.9])
    m, st = sim.model, sim.state
    air = sim.control.air.numpy()
    want = pressure_rows_np(st.x.numpy().astype(np.float64), m.host.faces, air, m.gas_rt, m.atmospheric_pressure,
                            1.0 / m.host.mass)
    for worlds in (3, 1):
        got = pressure_rows(m, st.x, air, worlds)
        for g, w in zip(got, want):
            assert g.shape[0] == worlds
            np.testing.assert_allclose(g, w[:worlds], rtol=1e-10, atol=1e-12 * float(np.abs(w).max()))
    assert not np.allclose(want[0][0], want[0][1])  # the worlds differ
