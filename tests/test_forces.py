"""Every force term against an independent float64 NumPy implementation, energies and symmetries."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import warp_shape as ws
from conftest import DEVICES, Scenario, rel_err
import reference as ref

TERMS = ["spring", "bending", "pressure", "ipam", "viscous"]
TOL = {"float64": 1e-9, "float32": 1e-4}


@pytest.fixture(scope="module", params=[(d, p) for d in DEVICES for p in ("float64", "float32")],
                ids=lambda dp: f"{dp[0]}-{dp[1]}")
def scenario(request):
    device, precision = request.param
    return Scenario(device=device, precision=precision)


@pytest.mark.parametrize("term", TERMS)
def test_term_matches_reference(scenario, term):
    got = scenario.sim.forces(term)
    want = scenario.reference_term(term)
    assert np.linalg.norm(want) > 0, "the scenario must exercise every term"
    assert rel_err(got, want) <= TOL[scenario.sim.precision], f"{term}: rel err {rel_err(got, want):.3e}"


def test_total_is_sum_of_terms(scenario):
    total = scenario.sim.forces()
    want = sum(scenario.reference_term(t) for t in TERMS)
    assert rel_err(total, want) <= TOL[scenario.sim.precision]


def test_paper_bending_matches_reference():
    s = Scenario(precision="float64", bending="paper")
    assert rel_err(s.sim.forces("bending"), s.reference_term("bending", "paper")) <= 1e-9
    # and differs from the exact gradient at the edge vertices
    assert rel_err(s.reference_term("bending", "paper"), s.reference_term("bending", "exact")) > 1e-3


# --------------------------------------------------------------------------- energies (finite differences)

def _central_gradient(fn, x, eps=1e-7):
    """Central finite-difference gradient of a scalar function of (V, 3) positions."""
    grad = np.zeros_like(x)
    for i in range(x.shape[0]):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, k] += eps
            xm[i, k] -= eps
            grad[i, k] = (fn(xp) - fn(xm)) / (2 * eps)
    return grad


def _small_sim(**material):
    rng = np.random.default_rng(3)
    rest = ws.icosphere(1, 0.04)
    mat = ws.Material(spring_damping=0.0, viscous_damping=0.0, **material)
    d = ws.Design(rest, mat)
    c = rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])), damping=0.0)
    d.add_cell([0, 1, 2, 3])
    sim = ws.Simulator(d, precision="float64")
    sim.positions = rest.vertices * 1.02 + rng.normal(0, 1e-3, rest.vertices.shape)
    sim.jam(0)
    x = rest.vertices * 1.04 + rng.normal(0, 1e-3, rest.vertices.shape)
    sim.positions = x
    sim.air_moles = sim.air_moles * 1.1
    sim.ipam_pressures = [30e3]
    return sim, x


@pytest.mark.parametrize("term,energy", [("spring", "spring"), ("bending", "bending"), ("ipam", "ipam"),
                                         ("pressure", "gas")])
def test_forces_are_minus_energy_gradient(term, energy):
    sim, x = _small_sim(bending_stiffness=3e-4)
    f = sim.forces(term)

    def energy_at(xq):
        sim.positions = xq
        return sim.energy()[energy]

    grad = _central_gradient(energy_at, x)
    sim.positions = x
    assert rel_err(f, -grad) < 1e-5, f"{term}: {rel_err(f, -grad):.2e}"


def test_pressure_force_is_p_times_volume_gradient():
    sim, x = _small_sim()
    p = sim.pressure()
    faces = sim.design.rest.faces
    dv = _central_gradient(lambda xq: ref.volume(xq, faces), x)
    assert abs(p) > 100.0
    assert rel_err(sim.forces("pressure"), p * dv) < 1e-6


# --------------------------------------------------------------------------- symmetries

def test_net_force_zero_and_torques():
    s = Scenario(precision="float64")
    sim = s.sim
    v = s.v - s.v.mean(axis=0)  # no net momentum, so viscous damping has no net force either
    sim.velocities = v
    scale = np.abs(sim.forces()).max()
    for term in TERMS:
        f = sim.forces(term)
        assert np.linalg.norm(f.sum(axis=0)) < 1e-9 * max(np.abs(f).max(), 1e-30) * len(f), term
    x = sim.positions
    torque = lambda f: np.cross(x - x.mean(0), f).sum(axis=0)  # noqa: E731
    fb = sim.forces("bending")
    arm = np.linalg.norm(x - x.mean(0), axis=1).mean()
    assert np.linalg.norm(torque(fb)) < 1e-9 * np.abs(fb).max() * arm * len(x)
    paper = ws.Simulator(s.design, precision="float64", bending="paper")
    paper.positions, paper.air_moles = x, sim.air_moles
    paper.jam(0)
    fp = paper.forces("bending")
    assert np.linalg.norm(fp.sum(axis=0)) < 1e-9 * np.abs(fp).max() * len(x)
    assert np.linalg.norm(torque(fp)) > 1e-3 * np.abs(fp).max() * arm, "paper bending must carry a net torque"
    assert scale > 0


def test_rigid_rotation_rotates_forces():
    s = Scenario(precision="float64")
    sim = s.sim
    f0 = sim.forces()
    th = 0.7
    axis = np.array([1.0, 2.0, -0.5])
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    Rm = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    # rotate about the origin: jammed rest values and IPAM rest data are rotation invariant
    sim.positions = s.x @ Rm.T
    sim.velocities = s.v @ Rm.T
    f1 = sim.forces()
    assert rel_err(f1, f0 @ Rm.T) < 1e-9


def test_float32_atan2_polynomial_within_float32_resolution():
    """The inlined float32 atan2 of the hinge pass stays within 1e-7 rad plus 1.5 float32 spacings of
    the exact angle in every quadrant, on the axes and at the origin (a library atan2f is good to
    about one spacing); float64 uses the library function itself."""
    import warp as wp
    from warp_shape.kernels.bending import hinge_atan2

    @wp.kernel
    def angles(y: wp.array(dtype=Any), x: wp.array(dtype=Any), out: wp.array(dtype=Any)):
        i = wp.tid()
        out[i] = hinge_atan2(y[i], x[i])

    rng = np.random.default_rng(3)
    r = 10.0 ** rng.uniform(-6, 3, 20000)
    t = rng.uniform(-np.pi, np.pi, r.size)
    y, x = r * np.sin(t), r * np.cos(t)
    special = np.array([[0, 1], [0, -1], [1, 0], [-1, 0], [0, 0], [1, 1], [-1, -1], [1e-30, -1], [-1e-30, -1]])
    y, x = np.concatenate([y, special[:, 0]]), np.concatenate([x, special[:, 1]])
    for dtype in (np.float32, np.float64):
        yd, xd = y.astype(dtype), x.astype(dtype)
        out = wp.zeros(y.size, dtype=wp.dtype_from_numpy(dtype), device="cpu")
        wp.launch(angles, y.size, [wp.array(yd, device="cpu"), wp.array(xd, device="cpu"), out], device="cpu")
        exact = np.arctan2(yd.astype(np.float64), xd.astype(np.float64))
        err = np.abs(out.numpy().astype(np.float64) - exact)
        err = np.minimum(err, 2 * np.pi - err)  # +-pi on the negative axis are the same angle
        tol = (1e-7 if dtype == np.float32 else 1e-15) + 1.5 * np.spacing(np.abs(exact).astype(dtype))
        assert np.all(err <= tol), (dtype, err.max(), y[err.argmax()], x[err.argmax()])


@pytest.mark.parametrize("subdivisions", [0, 2, 4])
def test_every_face_has_exactly_one_owner_hinge(subdivisions):
    """The fused pass adds each face's volume and dV/dx once: exactly one of its three hinges owns it."""
    from warp_shape.model import face_owners

    topo = ws.icosphere(subdivisions, 0.04).topology
    owns = face_owners(topo)
    count = np.zeros(topo.face_edges.shape[0], dtype=int)
    np.add.at(count, topo.faces[:, 0], owns & 1)
    np.add.at(count, topo.faces[:, 1], owns >> 1 & 1)
    assert np.all(count == 1)
