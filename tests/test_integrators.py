"""Convergence order, energy conservation, the analytic pressurized sphere, batching, determinism."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import warp_shape as ws


def _undamped_design(subdivisions=2):
    rest = ws.icosphere(subdivisions, 0.04)
    d = ws.Design(rest, ws.Material(spring_damping=0.0, viscous_damping=0.0, bending_stiffness=2e-4))
    c = rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])), damping=0.0)
    return d


def _perturbed(d, seed=1):
    rng = np.random.default_rng(seed)
    return d.rest.vertices * 1.01 + rng.normal(0, 3e-4, d.rest.vertices.shape)


def _run(d, x0, integrator, substeps, T=0.01, dt=1e-3):
    sim = ws.Simulator(d, integrator=integrator, precision="float64", dt=dt, substeps=substeps)
    sim.positions = x0
    sim.air_moles = sim.air_moles * 1.02
    sim.ipam_pressures = [20e3]
    sim.step(int(round(T / dt)))
    return sim.positions


@pytest.mark.parametrize("integrator,substeps,lo,hi", [("rk4", (4, 8, 16), 3.7, 4.3),
                                                       ("semi_implicit", (16, 32, 64), 0.8, 1.3)])
def test_convergence_order(integrator, substeps, lo, hi):
    d = _undamped_design()
    x0 = _perturbed(d)
    xs = [_run(d, x0, integrator, s) for s in substeps]
    e1 = np.abs(xs[0] - xs[1]).max()
    e2 = np.abs(xs[1] - xs[2]).max()
    order = np.log2(e1 / e2)
    assert lo <= order <= hi, f"{integrator}: observed order {order:.2f}"


def test_rk4_conserves_energy_without_damping():
    d = _undamped_design()
    sim = ws.Simulator(d, integrator="rk4", precision="float64", dt=1e-3, substeps=8)
    sim.positions = _perturbed(d)
    sim.air_moles = sim.air_moles * 1.02
    sim.ipam_pressures = [20e3]
    e0 = sim.energy()
    totals, kinetic = [e0["total"]], [0.0]
    for _ in range(50):  # 0.5 s
        sim.step(10)
        e = sim.energy()
        totals.append(e["total"])
        kinetic.append(e["kinetic"])
    drift = np.abs(np.array(totals) - totals[0]).max()
    assert drift / abs(totals[0]) < 1e-6
    # the stricter, meaningful scale: the energy that actually moves around
    assert max(kinetic) > 1e-4
    assert drift < 0.01 * max(kinetic), f"drift {drift:.3e} J vs max kinetic {max(kinetic):.3e} J"


def test_damping_dissipates_energy():
    d = ws.Design(ws.icosphere(2, 0.04))
    sim = ws.Simulator(d, precision="float64")
    sim.positions = _perturbed(d)
    energies = []
    for _ in range(10):
        sim.step(10)
        energies.append(sim.energy()["total"])
    assert np.all(np.diff(energies) <= 1e-12), "with dampers and fixed controls energy must not increase"


@pytest.mark.parametrize("precision,tol", [("float64", 1e-3), ("float32", 1e-3)])
def test_pressurized_sphere_matches_analytic_stretch(precision, tol):
    rest = ws.icosphere(2, 0.04)
    mat = ws.Material()
    sim = ws.Simulator(ws.Design(rest, mat), precision=precision, dt=1e-3)
    A0, V0 = rest.area(), rest.volume()
    lam = 1.15
    rt = ws.GAS_CONSTANT * mat.temperature
    # air for which lambda solves n R T / (V0 lam^3) - p_atm = E t A0 (lam - 1) / (V0 lam^2)
    sim.air_moles = (mat.atmospheric_pressure + mat.stretch_modulus * A0 * (lam - 1) / (V0 * lam**2)) * V0 * lam**3 / rt
    sim.step(400)
    assert sim.energy()["kinetic"] < 1e-8, "not settled"
    measured = (sim.volume() / V0) ** (1.0 / 3.0)
    assert abs(measured / lam - 1.0) < tol, f"stretch {measured:.6f} vs analytic {lam}"
    p_expected = mat.stretch_modulus * A0 * (lam - 1) / (V0 * lam**2)
    assert abs(sim.pressure() / p_expected - 1.0) < 5 * tol


def test_worlds_batch_equals_single_runs():
    d = _undamped_design()
    x0 = _perturbed(d)
    airs = np.array([1.0, 1.03, 1.06])
    batch = ws.Simulator(d, precision="float64", worlds=3, substeps=2)  # one internal step for all worlds
    batch.positions = x0
    batch.air_moles = batch.air_moles * airs
    batch.ipam_pressures = np.array([[0.0], [10e3], [20e3]])
    batch.step(20)
    for w in range(3):
        one = ws.Simulator(d, precision="float64", substeps=2)
        one.positions = x0
        one.air_moles = one.air_moles * airs[w]
        one.ipam_pressures = [10e3 * w]
        one.step(20)
        np.testing.assert_allclose(batch.positions[w], one.positions, rtol=0, atol=1e-12)


@pytest.mark.parametrize("mode", ["record", "direct"])
def test_launch_modes_identical(mode):
    d = _undamped_design()
    x0 = _perturbed(d)
    out = []
    for m in ("graph", mode):
        sim = ws.Simulator(d, precision="float32", launch_mode=m)
        sim.positions = x0
        sim.air_moles = sim.air_moles * 1.05
        sim.step(15)
        out.append((sim.positions, sim.volume()))  # the chamber volume: a captured graph in graph mode
    assert np.array_equal(out[0][0], out[1][0]) and out[0][1] == out[1][1]
    assert out[0][1] == pytest.approx(ws.TriMesh(out[0][0], d.rest.faces).volume(), rel=1e-6)


def test_stable_estimate_is_conservative():
    """At 95 % of the estimate a stiff, jammed, pressurized membrane stays bounded and settles."""
    rest = ws.icosphere(2, 0.04)
    d = ws.Design(rest, ws.Material(bending_stiffness=3e-4))
    d.add_cell(np.arange(rest.n_faces))
    probe = ws.Simulator(d, precision="float32")
    probe.air_moles = probe.air_moles * 1.3
    probe.jam(0)
    h = 0.95 * probe.stable_dt()
    sim = ws.Simulator(d, precision="float32", dt=h, substeps=1)
    sim.positions = _perturbed(d)
    sim.air_moles = probe.air_moles
    sim.jam(0)
    sim.step(2000)
    assert np.all(np.isfinite(sim.positions))
    assert sim.energy()["kinetic"] < 1e-3


@pytest.mark.skipif(not __import__("warp").is_cuda_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("integrator", ["rk4", "semi_implicit"])
def test_cuda_matches_cpu(integrator):
    d = _undamped_design()
    d.add_cell([0, 1, 2])
    x0 = _perturbed(d)
    out = []
    for device in ("cpu", "cuda:0"):
        sim = ws.Simulator(d, device=device, integrator=integrator, precision="float64", substeps=2)
        sim.positions = x0
        sim.air_moles = sim.air_moles * 1.05
        sim.ipam_pressures = [30e3]
        sim.step(10)
        sim.jam(0)
        sim.step(10)
        out.append(sim.positions)
    np.testing.assert_allclose(out[1], out[0], rtol=0, atol=1e-10)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_blowup_code_of_each_kind_of_vertex(precision):
    """flag_blowup gives each vertex its worst code (4 x non-finite, 3 v non-finite, 2 |x| > bound,
    1 |v| > bound), also where every component is finite but their sum overflows."""
    import warp as wp
    from warp_shape.kernels.integrate import flag_blowup

    @wp.kernel
    def flag(x: wp.array(dtype=Any), v: wp.array(dtype=Any), x_bound: Any, v_bound: Any,
             status: wp.array(dtype=wp.int32)):
        w = wp.tid()
        flag_blowup(x[w], v[w], x_bound, v_bound, w, status)

    big = float(np.finfo(precision).max) * 0.75  # finite, but two of them sum to inf
    nan, inf = np.nan, np.inf
    cases = [  # (x, v, code) with x_bound = 1 m, v_bound = 10 m/s
        ((0.5, 0, 0), (1, 0, 0), 0),
        ((nan, 0, 0), (1, 0, 0), 4), ((0, inf, 0), (1, 0, 0), 4), ((inf, -inf, 0), (1, 0, 0), 4),
        ((nan, 0, 0), (nan, 0, 0), 4),
        ((0, 0, 0), (0, 0, nan), 3), ((0, 0, 0), (-inf, 0, 0), 3), ((2, 0, 0), (inf, 0, 0), 3),
        ((2, 0, 0), (0, 0, 0), 2), ((big, big, 0), (0, 0, 0), 2), ((big, big, 0), (20, 0, 0), 2),
        ((0, 0, 0.5), (0, 20, 0), 1), ((0, 0, 0), (big, big, 0), 1), ((0, 0, 0), (0, -big, -big), 1),
    ]
    vec = wp.vec3f if precision == "float32" else wp.vec3d
    x = wp.array(np.array([c[0] for c in cases], dtype=precision), dtype=vec, device="cpu")
    v = wp.array(np.array([c[1] for c in cases], dtype=precision), dtype=vec, device="cpu")
    status = wp.zeros(len(cases), dtype=wp.int32, device="cpu")
    scalar = wp.float32 if precision == "float32" else wp.float64
    wp.launch(flag, len(cases), [x, v, scalar(1.0), scalar(10.0), status], device="cpu")
    assert status.numpy().tolist() == [c[2] for c in cases]
