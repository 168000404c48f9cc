"""Self-checks of the float64 NumPy reference model (tests/reference.py).

These tests prove the oracle right on its own terms (finite differences, invariances,
closed-form cases) so that it can be trusted when the simulator kernels are compared
against it.
"""

from __future__ import annotations

import itertools
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import reference as ref  # noqa: E402

FD_STEP = 1e-6  # the test sphere has radius 0.1 and edges of about 0.02
FD_RTOL = 1e-6


# ----------------------------------------------------------------------------------
# fixtures and utilities
# ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mesh():
    """Perturbed icosphere with random velocities and per-edge parameters."""
    rng = np.random.default_rng(1234)
    x, f = ref.random_perturbed_icosphere(2, radius=0.1, noise=0.03, seed=7)
    h = ref.hinges(f)
    v = 0.05 * rng.standard_normal(x.shape)
    x_rest, _ = ref.icosphere(2, radius=0.1)
    rest_len = ref.edge_lengths(x_rest, h)
    k = ref.spring_stiffness(x_rest, f, h, E_modulus=1.2e6, thickness=2e-3)
    theta0 = ref.dihedral(x_rest, h) + 0.05 * rng.standard_normal(h.shape[0])
    kt = 1e-3 * (1.0 + rng.random(h.shape[0]))
    return dict(x=x, v=v, f=f, h=h, rest_len=rest_len, k=k, theta0=theta0, kt=kt, rng=rng)


def fd_gradient(energy, x, step=FD_STEP):
    """Central finite-difference gradient of a scalar function of ``x`` (V, 3)."""
    x = np.array(x, dtype=np.float64)
    g = np.zeros_like(x)
    for i in range(x.shape[0]):
        for d in range(3):
            xp = x.copy()
            xm = x.copy()
            xp[i, d] += step
            xm[i, d] -= step
            g[i, d] = (energy(xp) - energy(xm)) / (2.0 * step)
    return g


def rel_err(a, b):
    return np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def single_hinge(rng, fold=0.0):
    """One hinge: faces (0, 1, 2) and (1, 0, 3), random shape, optional fold."""
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0],
                  [0.3 + 0.4 * rng.random(), 0.7 + 0.5 * rng.random(), 0.0],
                  [0.1 + 0.8 * rng.random(), -0.6 - 0.5 * rng.random(), 0.0]])
    x[2, 0] += rng.uniform(-0.5, 0.5)
    x[3, 0] += rng.uniform(-0.5, 0.5)
    # fold wing 3 around the x axis by `fold` (positive = convex with +z outward)
    c, s = np.cos(fold), np.sin(fold)
    x[3] = np.array([x[3, 0], c * x[3, 1], s * x[3, 1]])
    f = np.array([[0, 1, 2], [1, 0, 3]])
    return x, f


def ipam_setup(mesh):
    """An IPAM between two roughly opposite faces of the sphere."""
    x_rest, f = ref.icosphere(2, radius=0.1)
    cent = x_rest[f].mean(axis=1)
    a = 0
    b = int(np.argmin(cent @ cent[a]))
    pairs, offsets = ref.ipam_pairs(x_rest, f, a, b)
    L_rest = ref.ipam_length(x_rest, f, a, b)
    return dict(a=a, b=b, pairs=pairs, offsets=offsets, k=150.0, area=3e-4,
                L0=0.9 * L_rest, P=2.5e4, c_d=0.7)


def all_forces(x, v, mesh, ip, n_mol):
    """Every force term, keyed by name, at (x, v)."""
    f, h = mesh["f"], mesh["h"]
    p = ref.pressure(n_mol, ref.volume(x, f))
    return {
        "spring": ref.spring_forces(x, v, h, mesh["rest_len"], mesh["k"], 0.3),
        "bend_exact": ref.bending_forces_exact(x, h, mesh["theta0"], mesh["kt"]),
        "bend_paper": ref.bending_forces_paper(x, h, mesh["theta0"], mesh["kt"]),
        "pressure": ref.pressure_forces(x, f, p),
        "ipam": ref.ipam_forces(x, v, ip["pairs"], ip["offsets"], ip["k"], ip["area"],
                                ip["L0"], ip["P"], ip["c_d"]),
        "viscous": ref.damping_forces(v, 0.2),
    }


def n_for_gauge(x, f, p_gauge, T=ref.T_DEFAULT, p_atm=ref.P_ATM_DEFAULT):
    return (p_gauge + p_atm) * ref.volume(x, f) / (ref.R_GAS * T)


# ----------------------------------------------------------------------------------
# topology and mesh
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize("s", [0, 1, 2, 3])
def test_icosphere_counts_and_winding(s):
    x, f = ref.icosphere(s, radius=2.5)
    assert x.shape == (10 * 4**s + 2, 3)
    assert f.shape == (20 * 4**s, 3)
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 2.5, rtol=1e-12)
    n = ref.face_normals(x, f)
    assert np.all(np.einsum("ij,ij->i", n, x[f].mean(axis=1)) > 0)
    h = ref.hinges(f)
    assert h.shape == (30 * 4**s, 4)
    assert np.all(h[:, 3] >= 0)
    assert ref.volume(x, f) > 0


def test_perturbed_icosphere_is_seeded():
    a, fa = ref.random_perturbed_icosphere(2, 1.0, 0.01, seed=3)
    b, fb = ref.random_perturbed_icosphere(2, 1.0, 0.01, seed=3)
    c, _ = ref.random_perturbed_icosphere(2, 1.0, 0.01, seed=4)
    u, _ = ref.icosphere(2, 1.0)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fa, fb)
    assert not np.array_equal(a, c)
    assert 0.005 < np.std(a - u) < 0.02


def test_hinges_structure(mesh):
    f, h = mesh["f"], mesh["h"]
    cyc = set()
    for a, b, c in f:
        cyc |= {(a, b, c), (b, c, a), (c, a, b)}
    for v0, v1, v2, v3 in h:
        assert (v0, v1, v2) in cyc
        assert (v1, v0, v3) in cyc
        assert v0 < v1
    keys = [ref.edge_key(a, b) for a, b in h[:, :2]]
    assert keys == sorted(keys)
    assert len(set(keys)) == len(keys)
    all_edges = {ref.edge_key(a, b) for tri in f for a, b in itertools.combinations(tri, 2)}
    assert set(keys) == all_edges
    assert ref.edge_key(5, 2) == (2, 5) == ref.edge_key(2, 5)


def test_hinges_boundary_and_errors():
    f = np.array([[0, 1, 2], [1, 0, 3]])
    h, hf = ref.hinges(f, return_faces=True)
    assert h.shape == (5, 4)
    row = [r for r in h if ref.edge_key(r[0], r[1]) == (0, 1)][0]
    assert tuple(row) == (0, 1, 2, 3)
    assert np.sum(h[:, 3] == -1) == 4
    assert np.all(hf[h[:, 3] == -1, 1] == -1)
    with pytest.raises(ValueError):
        ref.hinges(np.array([[0, 1, 2], [0, 1, 3]]))  # inconsistent winding


def test_cell_edge_mask(mesh):
    f, h = mesh["f"], mesh["h"]
    m = ref.cell_edge_mask(f, [0, 1])
    expected = {ref.edge_key(a, b) for t in f[[0, 1]] for a, b in itertools.combinations(t, 2)}
    got = {ref.edge_key(a, b) for a, b in h[m, :2]}
    assert got == expected


# ----------------------------------------------------------------------------------
# mass and stiffness
# ----------------------------------------------------------------------------------
def test_vertex_masses(mesh):
    x, f = mesh["x"], mesh["f"]
    m = ref.vertex_masses(x, f, 1.7)
    assert np.all(m > 0)
    np.testing.assert_allclose(m.sum(), 1.7 * ref.face_areas(x, f).sum(), rtol=1e-13)
    # a single triangle: each vertex gets a third
    xt = np.array([[0, 0, 0], [2, 0, 0], [0, 3, 0]], dtype=float)
    np.testing.assert_allclose(ref.vertex_masses(xt, [[0, 1, 2]], 2.0), [2.0] * 3)


def test_spring_stiffness_closed_form():
    # unit square split along its diagonal (0, 2): faces (0,1,2) and (0,2,3), each area 1/2
    x = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    h = ref.hinges(f)
    k = ref.spring_stiffness(x, f, h, E_modulus=3.0, thickness=0.5)
    for row, ke in zip(h, k):
        key = ref.edge_key(row[0], row[1])
        if key == (0, 2):  # diagonal: A = 1, c^2 = 2
            assert ke == pytest.approx(3.0 * 0.5 * 1.0 / 2.0)
        else:  # boundary sides: A = 1/2, c^2 = 1
            assert ke == pytest.approx(3.0 * 0.5 * 0.5 / 1.0)


# ----------------------------------------------------------------------------------
# force = -grad(energy) by finite differences
# ----------------------------------------------------------------------------------
def test_spring_forces_fd(mesh):
    x, h = mesh["x"], mesh["h"]
    F = ref.spring_forces(x, mesh["v"], h, mesh["rest_len"], mesh["k"], 0.0)
    g = fd_gradient(lambda y: ref.spring_energy(y, h, mesh["rest_len"], mesh["k"]), x)
    assert rel_err(F, -g) < FD_RTOL


def test_spring_damper_is_rayleigh(mesh):
    x, v, h = mesh["x"], mesh["v"], mesh["h"]
    c_s = 0.4
    Fd = ref.spring_forces(x, v, h, mesh["rest_len"], mesh["k"], c_s) - \
        ref.spring_forces(x, v, h, mesh["rest_len"], mesh["k"], 0.0)
    g = fd_gradient(lambda w: ref.spring_damper_dissipation(x, w, h, c_s), v)
    assert rel_err(Fd, -g) < FD_RTOL
    assert np.sum(Fd * v) < 0  # dissipative


def test_single_spring_formula():
    x = np.array([[0.0, 0, 0], [2.0, 0, 0]])
    v = np.array([[0.0, 0, 0], [0.5, 0.3, 0]])
    F = ref.spring_forces(x, v, np.array([[0, 1, -1, -1]]), [1.5], [10.0], 2.0)
    # f_0 = [10 * 0.5 + 2 * 0.5] * (+x) = 6 x^
    np.testing.assert_allclose(F, [[6, 0, 0], [-6, 0, 0]], atol=1e-14)


def test_dihedral_gradient_fd(mesh):
    x, h = mesh["x"], mesh["h"]
    g = ref.dihedral_gradient(x, h)
    # check a handful of hinges coordinate by coordinate
    for e in [0, 17, 123, 301, len(h) - 1]:
        for j in range(4):
            for d in range(3):
                xp, xm = x.copy(), x.copy()
                xp[h[e, j], d] += FD_STEP
                xm[h[e, j], d] -= FD_STEP
                fd = (ref.dihedral(xp, h)[e] - ref.dihedral(xm, h)[e]) / (2 * FD_STEP)
                assert g[e, j, d] == pytest.approx(fd, rel=1e-6, abs=1e-6 * np.abs(g[e]).max())


def test_bending_exact_forces_fd(mesh):
    x, h = mesh["x"], mesh["h"]
    F = ref.bending_forces_exact(x, h, mesh["theta0"], mesh["kt"])
    g = fd_gradient(lambda y: ref.bending_energy(y, h, mesh["theta0"], mesh["kt"]), x)
    assert rel_err(F, -g) < FD_RTOL


def test_bending_scalar_kt_matches_array(mesh):
    x, h = mesh["x"], mesh["h"]
    a = ref.bending_forces_exact(x, h, mesh["theta0"], 2e-3)
    b = ref.bending_forces_exact(x, h, mesh["theta0"], np.full(len(h), 2e-3))
    np.testing.assert_array_equal(a, b)
    assert ref.bending_energy(x, h, 0.0, 2e-3) == pytest.approx(
        ref.bending_energy(x, h, np.zeros(len(h)), np.full(len(h), 2e-3)))


def test_ipam_forces_fd(mesh):
    ip = ipam_setup(mesh)
    x = mesh["x"]
    F = ref.ipam_forces(x, mesh["v"], ip["pairs"], ip["offsets"], ip["k"], ip["area"],
                        ip["L0"], ip["P"], 0.0)
    g = fd_gradient(lambda y: ref.ipam_energy(y, ip["pairs"], ip["offsets"], ip["k"],
                                              ip["area"], ip["L0"], ip["P"]), x)
    assert rel_err(F, -g) < FD_RTOL
    assert np.count_nonzero(np.abs(F).sum(axis=1)) == 6


def test_pressure_forces_fd(mesh):
    x, f = mesh["x"], mesh["f"]
    p = 2345.0
    F = ref.pressure_forces(x, f, p)
    dV = fd_gradient(lambda y: ref.volume(y, f), x)
    assert rel_err(F, p * dV) < FD_RTOL
    assert rel_err(ref.volume_gradient(x, f), dV) < FD_RTOL
    # through the gas energy with n chosen for the same gauge pressure
    n = n_for_gauge(x, f, p)
    assert ref.pressure(n, ref.volume(x, f)) == pytest.approx(p, rel=1e-10)
    g = fd_gradient(lambda y: ref.gas_energy(y, f, n), x, step=1e-5)
    assert rel_err(F, -g) < FD_RTOL


def test_volume_closed_form():
    # unit cube, outward winding
    x = np.array(list(itertools.product([0, 1], repeat=3)), dtype=float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    assert ref.volume(x, f) == pytest.approx(1.0)
    assert ref.volume(x + 7.0, f) == pytest.approx(1.0)
    xs, fs = ref.icosphere(4, 1.0)
    assert ref.volume(xs, fs) == pytest.approx(4.0 / 3.0 * np.pi, rel=5e-3)
    assert ref.pressure(1.0, 0.5, T=300.0, p_atm=1e5) == pytest.approx(
        ref.R_GAS * 300.0 / 0.5 - 1e5)


def test_total_forces_fd(mesh):
    x, f, h = mesh["x"], mesh["f"], mesh["h"]
    ip = ipam_setup(mesh)
    n = n_for_gauge(x, f, 800.0)
    kw = dict(rest_len=mesh["rest_len"], k=mesh["k"], theta0=mesh["theta0"], kt=mesh["kt"],
              n=n, ipams=[{k: ip[k] for k in ("pairs", "offsets", "k", "area", "L0", "P")}])
    F = ref.total_forces(x, np.zeros_like(x), f, h, **kw)
    g = fd_gradient(lambda y: ref.total_energy(y, f, h, **kw), x)
    assert rel_err(F, -g) < FD_RTOL


# ----------------------------------------------------------------------------------
# momentum: net force and net torque
# ----------------------------------------------------------------------------------
def test_net_force_zero(mesh):
    x, v, f = mesh["x"], mesh["v"], mesh["f"]
    ip = ipam_setup(mesh)
    forces = all_forces(x, v, mesh, ip, n_for_gauge(x, f, 1500.0))
    for name, F in forces.items():
        if name == "viscous":  # -c_v v: external drag, zero only for zero momentum
            vv = v - v.mean(axis=0)
            assert np.linalg.norm(ref.net_force(ref.damping_forces(vv, 0.2))) < 1e-14
            continue
        scale = np.abs(F).sum()
        assert scale > 0, name
        assert np.linalg.norm(ref.net_force(F)) < 1e-12 * scale, name


def test_net_torque(mesh):
    x, v, f = mesh["x"], mesh["v"], mesh["f"]
    ip = ipam_setup(mesh)
    forces = all_forces(x, v, mesh, ip, n_for_gauge(x, f, 1500.0))
    radius = np.linalg.norm(x, axis=1).max()
    origin = np.array([0.3, -0.2, 0.5])  # torque-free must hold about any point
    for name in ("spring", "bend_exact", "pressure", "ipam"):
        F = forces[name]
        scale = np.abs(F).sum() * radius
        assert np.linalg.norm(ref.net_torque(x, F, origin)) < 1e-12 * scale, name
    Fp = forces["bend_paper"]
    typical = np.linalg.norm(Fp, axis=1).mean() * radius  # typical |force| * radius
    tq = np.linalg.norm(ref.net_torque(x, Fp))
    assert tq > 0.05 * typical
    scale = np.linalg.norm(Fp, axis=1).sum() * radius
    # but its net force is still zero
    assert np.linalg.norm(ref.net_force(Fp)) < 1e-12 * scale


# ----------------------------------------------------------------------------------
# dihedral angle conventions
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize("s", [0, 1, 2, 3])
def test_dihedral_sphere_positive(s):
    x, f = ref.icosphere(s, 3.0)
    th = ref.dihedral(x, ref.hinges(f))
    assert np.all(th > 0)
    assert np.all(th < np.pi)


def test_dihedral_icosahedron_closed_form():
    x, f = ref.icosphere(0, 1.0)
    th = ref.dihedral(x, ref.hinges(f))
    # icosahedron interior dihedral angle arccos(-sqrt(5)/3); normals turn by pi minus it
    np.testing.assert_allclose(th, np.pi - np.arccos(-np.sqrt(5) / 3), rtol=1e-12)


def test_dihedral_tetrahedron_closed_form():
    x = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    assert ref.volume(x, f) > 0
    th = ref.dihedral(x, ref.hinges(f))
    np.testing.assert_allclose(th, np.pi - np.arccos(1.0 / 3.0), rtol=1e-12)
    # inside-out winding gives the negated angles
    th_in = ref.dihedral(x, ref.hinges(f[:, [0, 2, 1]]))
    np.testing.assert_allclose(th_in, -(np.pi - np.arccos(1.0 / 3.0)), rtol=1e-12)


def test_dihedral_flat_and_folded():
    rng = np.random.default_rng(0)
    x, f = single_hinge(rng)
    h = ref.hinges(f)
    row = np.flatnonzero(h[:, 3] >= 0)
    assert ref.dihedral(x, h)[row] == pytest.approx([0.0], abs=1e-15)
    for fold in [0.3, 1.2, -0.7, np.pi - 1e-3, -(np.pi - 1e-3)]:
        x, f = single_hinge(rng, fold)
        th = ref.dihedral(x, ref.hinges(f))[row][0]
        assert th == pytest.approx(fold, abs=1e-12)
    # a fully folded hinge is +pi, never -pi
    x, f = single_hinge(rng, np.pi)
    th = ref.dihedral(x, ref.hinges(f))[row][0]
    assert -np.pi < th <= np.pi and abs(abs(th) - np.pi) < 1e-12
    # swapping the roles of the faces gives the same angle
    x, f = single_hinge(rng, 0.8)
    h = ref.hinges(f)[row]
    swapped = h[:, [1, 0, 3, 2]]
    assert ref.dihedral(x, swapped)[0] == pytest.approx(ref.dihedral(x, h)[0], abs=1e-14)


def test_dihedral_in_range_on_perturbed(mesh):
    th = ref.dihedral(mesh["x"], mesh["h"])
    assert np.all(th > -np.pi) and np.all(th <= np.pi)


# ----------------------------------------------------------------------------------
# rigid-motion equivariance
# ----------------------------------------------------------------------------------
def test_rotation_equivariance(mesh):
    x, v, f = mesh["x"], mesh["v"], mesh["f"]
    ip = ipam_setup(mesh)
    R = random_rotation(np.random.default_rng(99))
    n = n_for_gauge(x, f, 1500.0)
    base = all_forces(x, v, mesh, ip, n)
    rot = all_forces(x @ R.T, v @ R.T, mesh, ip, n)
    for name in base:
        assert rel_err(rot[name], base[name] @ R.T) < 1e-12, name
    # translation invariance of the position-dependent terms
    shifted = all_forces(x + np.array([1.0, -2.0, 0.5]), v, mesh, ip, n)
    for name in base:
        assert rel_err(shifted[name], base[name]) < 1e-9, name


# ----------------------------------------------------------------------------------
# paper bending variant
# ----------------------------------------------------------------------------------
def test_paper_wing_forces_equal_exact():
    rng = np.random.default_rng(5)
    for fold in [0.4, -0.9, 2.0]:
        x, f = single_hinge(rng, fold)
        x = x + 0.05 * rng.standard_normal(x.shape)
        h = ref.hinges(f)
        theta0 = rng.uniform(-0.5, 0.5, len(h))
        Fe = ref.bending_forces_exact(x, h, theta0, 0.7)
        Fp = ref.bending_forces_paper(x, h, theta0, 0.7)
        # vertices 2 and 3 are the wings of the only interior hinge
        np.testing.assert_allclose(Fp[2:], Fe[2:], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(Fp[0], Fp[1], rtol=1e-12)
        np.testing.assert_allclose(Fp[0], -0.5 * (Fp[2] + Fp[3]), rtol=1e-12)
        # the edge vertices carry the same total in both variants
        np.testing.assert_allclose(Fp[0] + Fp[1], Fe[0] + Fe[1], rtol=1e-12, atol=1e-14)
        # wing force follows the paper's magnitude tau / |r|
        th = ref.dihedral(x, h)[h[:, 3] >= 0][0]
        tau = -0.7 * (th - theta0[h[:, 3] >= 0][0])
        e = x[1] - x[0]
        r = np.linalg.norm(np.cross(e, x[2] - x[0])) / np.linalg.norm(e)
        assert np.linalg.norm(Fp[2]) == pytest.approx(abs(tau) / r, rel=1e-12)


def test_paper_matches_exact_on_symmetric_hinge():
    # wings project onto the edge midpoint: projection weights are 1/2 and the variants agree
    x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.8, 0.1], [0.5, -0.6, 0.3]], dtype=float)
    f = np.array([[0, 1, 2], [1, 0, 3]])
    h = ref.hinges(f)
    np.testing.assert_allclose(ref.bending_forces_paper(x, h, 0.0, 1.3),
                               ref.bending_forces_exact(x, h, 0.0, 1.3), rtol=1e-12, atol=1e-15)


# ----------------------------------------------------------------------------------
# IPAM
# ----------------------------------------------------------------------------------
def test_ipam_pairs_min_permutation(mesh):
    x_rest, f = ref.icosphere(2, radius=0.1)
    ip = ipam_setup(mesh)
    pairs = ip["pairs"]
    assert list(pairs[:, 0]) == list(f[ip["a"]])
    assert sorted(pairs[:, 1]) == sorted(f[ip["b"]])
    best = min(sum(np.linalg.norm(x_rest[q] - x_rest[p]) for p, q in zip(f[ip["a"]], perm))
               for perm in itertools.permutations(f[ip["b"]]))
    got = sum(np.linalg.norm(x_rest[q] - x_rest[p]) for p, q in pairs)
    assert got == pytest.approx(best, rel=1e-14)
    L = ref.ipam_length(x_rest, f, ip["a"], ip["b"])
    np.testing.assert_allclose(ip["offsets"],
                               np.linalg.norm(x_rest[pairs[:, 1]] - x_rest[pairs[:, 0]], axis=1) - L)
    # at the rest shape with L_n equal to the rest centroid distance there is no force
    P = (L - ip["L0"]) * ip["k"] / ip["area"]
    assert ref.ipam_natural_length(ip["k"], ip["area"], ip["L0"], P) == pytest.approx(L)
    F = ref.ipam_forces(x_rest, np.zeros_like(x_rest), pairs, ip["offsets"], ip["k"],
                        ip["area"], ip["L0"], P, ip["c_d"])
    assert np.abs(F).max() < 1e-12


def test_ipam_axial_force_parallel_faces():
    # congruent parallel triangles 0.2 apart along z; the right pairing is vertex i -> i+3
    tri = np.array([[0.01, 0, 0], [-0.005, 0.0087, 0], [-0.005, -0.0087, 0]])
    x_rest = np.vstack([tri, tri + [0, 0, 0.2]])
    f = np.array([[0, 1, 2], [3, 5, 4]])  # face b wound the other way: faces each other
    pairs, offsets = ref.ipam_pairs(x_rest, f, 0, 1)
    np.testing.assert_array_equal(pairs, [[0, 3], [1, 4], [2, 5]])
    np.testing.assert_allclose(offsets, 0.0, atol=1e-15)
    k, area, L0, P = 200.0, 1e-4, 0.15, 3e4
    Ln = ref.ipam_natural_length(k, area, L0, P)
    assert Ln == pytest.approx(L0 + area / k * P)
    for L in [0.17, 0.18, 0.25]:
        x = np.vstack([tri, tri + [0, 0, L]])
        Fax = ref.ipam_axial_force(x, f, 0, 1, k, area, L0, P)
        assert Fax == pytest.approx(k * (L - Ln))
        F = ref.ipam_forces(x, np.zeros_like(x), pairs, offsets, k, area, L0, P, 0.0)
        # tension pulls face a toward face b (+z) with total magnitude k (L - L_n)
        np.testing.assert_allclose(F[:3].sum(axis=0), [0, 0, Fax], atol=1e-12)
        np.testing.assert_allclose(F[3:].sum(axis=0), [0, 0, -Fax], atol=1e-12)
        assert (Fax > 0) == (L > Ln)
    # damper: face b receding at speed u gives an extra pull c_d * u per sub-spring
    x = np.vstack([tri, tri + [0, 0, Ln]])
    v = np.zeros_like(x)
    v[3:, 2] = 0.5
    F = ref.ipam_forces(x, v, pairs, offsets, k, area, L0, P, 0.8)
    np.testing.assert_allclose(F[:3, 2], 0.8 * 0.5, rtol=1e-12)
    np.testing.assert_allclose(F[3:, 2], -0.8 * 0.5, rtol=1e-12)


# ----------------------------------------------------------------------------------
# viscous damping
# ----------------------------------------------------------------------------------
def test_damping_forces():
    v = np.arange(12.0).reshape(4, 3)
    np.testing.assert_array_equal(ref.damping_forces(v, 0.5), -0.5 * v)
    cv = np.array([1.0, 2.0, 0.0, 3.0])
    np.testing.assert_array_equal(ref.damping_forces(v, cv), -cv[:, None] * v)


# ----------------------------------------------------------------------------------
# jamming
# ----------------------------------------------------------------------------------
def test_jam_once(mesh):
    x, f, h = mesh["x"], mesh["f"], mesh["h"]
    kt = 2e-3
    mask1 = ref.cell_edge_mask(f, [0, 1, 2, 3])
    mask2 = ref.cell_edge_mask(f, [3, 4, 5, 6])  # shares face 3's edges with cell 1
    assert np.any(mask1 & mask2)

    r1, t1, k1, kt1, j1 = ref.jam(x, h, mask1, mesh["rest_len"], mesh["theta0"], mesh["k"], kt)
    np.testing.assert_allclose(r1[mask1], ref.edge_lengths(x, h)[mask1])
    np.testing.assert_allclose(t1[mask1], ref.dihedral(x, h)[mask1])
    np.testing.assert_allclose(k1[mask1], 10 * mesh["k"][mask1])
    np.testing.assert_allclose(kt1[mask1], 30 * kt)
    np.testing.assert_array_equal(r1[~mask1], mesh["rest_len"][~mask1])
    np.testing.assert_array_equal(t1[~mask1], mesh["theta0"][~mask1])
    np.testing.assert_array_equal(k1[~mask1], mesh["k"][~mask1])
    np.testing.assert_array_equal(kt1[~mask1], kt)
    np.testing.assert_array_equal(j1, mask1)

    # the same mask again, in a moved configuration: nothing changes
    x_moved = x * 1.05
    r2, t2, k2, kt2, j2 = ref.jam(x_moved, h, mask1, r1, t1, k1, kt1, already=j1)
    for a, b in [(r2, r1), (t2, t1), (k2, k1), (kt2, kt1), (j2, j1)]:
        np.testing.assert_array_equal(a, b)

    # an overlapping second cell stiffens only its new edges
    r3, t3, k3, kt3, j3 = ref.jam(x_moved, h, mask2, r1, t1, k1, kt1, already=j1)
    shared = mask1 & mask2
    new = mask2 & ~mask1
    np.testing.assert_array_equal(k3[shared], k1[shared])
    np.testing.assert_array_equal(kt3[shared], kt1[shared])
    np.testing.assert_array_equal(r3[shared], r1[shared])
    np.testing.assert_allclose(k3[new], 10 * mesh["k"][new])
    np.testing.assert_allclose(kt3[new], 30 * kt)
    np.testing.assert_allclose(r3[new], ref.edge_lengths(x_moved, h)[new])
    np.testing.assert_array_equal(j3, mask1 | mask2)
    assert np.all(k3 <= 10 * mesh["k"] * (1 + 1e-15))

    # right after jamming, jammed edges exert no spring or bending force
    only = np.zeros(len(h), dtype=bool)
    only[mask1] = True
    Fs = ref.spring_forces(x, None, h[only], r1[only], k1[only])
    Fb = ref.bending_forces_exact(x, h[only], t1[only], kt1[only])
    assert np.abs(Fs).max() < 1e-12 and np.abs(Fb).max() < 1e-12


def test_jam_custom_factors(mesh):
    x, h = mesh["x"], mesh["h"]
    mask = np.zeros(len(h), dtype=bool)
    mask[:5] = True
    _, _, k, kt, _ = ref.jam(x, h, mask, mesh["rest_len"], mesh["theta0"], mesh["k"], 1.0,
                             stretch_factor=3.0, bend_factor=7.0)
    np.testing.assert_allclose(k[:5], 3.0 * mesh["k"][:5])
    np.testing.assert_allclose(kt[:5], 7.0)
    np.testing.assert_allclose(kt[5:], 1.0)
