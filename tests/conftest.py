"""Shared fixtures: a small, fully featured design in a perturbed, moving state."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import warp as wp

# the suite runs in one process unless a test asks for workers (tests/test_shard.py; docs/performance.md)
os.environ["WARP_SHAPE_WORKERS"] = "1"
wp.config.quiet = True
wp.config.log_level = wp.LOG_WARNING
sys.path.insert(0, os.path.dirname(__file__))

import reference as ref  # noqa: E402

import warp_shape as ws  # noqa: E402
from warp_shape.controller.shard import available_cores  # noqa: E402

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``make test``'s ``-n auto``: a pytest process per core this one may use, at most 4 (a test that
    designs on a run's workers starts its own processes, and each process compiles what it loads)."""
    return min(4, available_cores())


def with_pressure_max(design: ws.Design, p_max: float) -> ws.Design:
    """A copy of ``design`` whose IPAMs' upper pressure limit is ``p_max`` (Pa gauge)."""
    out = ws.Design(design.rest, design.material)
    for ip in design.ipams:
        out.add_ipam(ip.face_a, ip.face_b, stiffness=ip.stiffness, area=ip.area,
                     pressure_limits=(ip.pressure_limits[0], p_max), damping=ip.damping)
    for c in design.cells:
        out.add_cell(c.faces)
    return out


def rel_err(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


class Scenario:
    """A design with every force family, jammed once, then perturbed and moving.

    ``oracle`` holds the matching parameters for tests/reference.py, computed independently.
    """

    def __init__(self, device="cpu", precision="float64", bending="exact", subdivisions=2, seed=7):
        rng = np.random.default_rng(seed)
        rest = ws.icosphere(subdivisions, 0.04)
        mat = ws.Material(bending_stiffness=2e-4, spring_damping=0.01, viscous_damping=0.03)
        d = ws.Design(rest, mat)
        c = rest.face_centroids()
        # two IPAMs between nearly opposite faces, a jamming cell around one end of each
        a0 = int(np.argmax(c[:, 2]))
        b0 = int(np.argmin(c[:, 2]))
        a1 = int(np.argmax(c[:, 0]))
        b1 = int(np.argmin(c[:, 0]))
        d.add_ipam(a0, b0, stiffness=60.0, area=2e-5, free_length=0.07, damping=0.004)
        d.add_ipam(a1, b1, stiffness=40.0, area=1e-5, damping=0.002)
        near0 = np.flatnonzero(np.linalg.norm(c - c[a0], axis=1) < 0.012)
        near1 = np.flatnonzero(np.linalg.norm(c - c[b1], axis=1) < 0.012)
        d.add_cell(near0)
        d.add_cell(np.setdiff1d(near1, near0))
        self.design, self.rest, self.mat = d, rest, mat
        sim = ws.Simulator(d, device=device, precision=precision, bending=bending)
        x0 = rest.vertices
        noise = 0.02 * 0.04
        x_jam = x0 * 1.03 + rng.normal(0, noise, x0.shape)
        sim.positions = x_jam
        sim.jam(0)
        x = x0 * 1.05 + rng.normal(0, noise, x0.shape)
        v = rng.normal(0, 0.05, x0.shape)
        sim.positions = x
        sim.velocities = v
        V = rest.copy_with(x).volume()
        sim.air_moles = (mat.atmospheric_pressure + 2000.0) * V / (ws.GAS_CONSTANT * mat.temperature)
        sim.ipam_pressures = [40e3, -10e3]
        self.sim = sim
        # what the simulator actually holds (float32 rounding included)
        self.x, self.v = sim.positions, sim.velocities
        self.x_jam = np.asarray(x_jam, dtype=np.float32 if precision == "float32" else np.float64).astype(np.float64)

        faces = rest.faces
        H = ref.hinges(faces)
        k = ref.spring_stiffness(x0, faces, H, mat.youngs_modulus, mat.thickness)
        L = ref.edge_lengths(x0, H)
        th = ref.dihedral(x0, H)
        mask = ref.cell_edge_mask(faces, d.cells[0].faces)
        L, th, k, kt, _ = ref.jam(self.x_jam, H, mask, L, th, k, mat.bending_stiffness,
                                  mat.jam_stretch_factor, mat.jam_bend_factor)
        ipams = []
        for ip, P in zip(d.ipams, [40e3, -10e3]):
            pairs, offsets = ref.ipam_pairs(x0, faces, ip.face_a, ip.face_b)
            ipams.append(dict(pairs=pairs, offsets=offsets, k=ip.stiffness, area=ip.area, L0=ip.free_length,
                              P=P, c_d=ip.damping))
        self.oracle = dict(faces=faces, hinges=H, rest_len=L, k=k, theta0=th, kt=kt, c_s=mat.spring_damping,
                           c_v=mat.viscous_damping, n=sim.air_moles, T=mat.temperature,
                           p_atm=mat.atmospheric_pressure, ipams=ipams)

    def reference_term(self, term: str, bending="exact") -> np.ndarray:
        o, x, v = self.oracle, self.x, self.v
        if term == "spring":
            return ref.spring_forces(x, v, o["hinges"], o["rest_len"], o["k"], o["c_s"])
        if term == "bending":
            fn = ref.bending_forces_exact if bending == "exact" else ref.bending_forces_paper
            return fn(x, o["hinges"], o["theta0"], o["kt"])
        if term == "pressure":
            p = ref.pressure(o["n"], ref.volume(x, o["faces"]), o["T"], o["p_atm"])
            return ref.pressure_forces(x, o["faces"], p)
        if term == "viscous":
            return ref.damping_forces(v, o["c_v"])
        if term == "ipam":
            return sum(ref.ipam_forces(x, v, ip["pairs"], ip["offsets"], ip["k"], ip["area"], ip["L0"], ip["P"],
                                       ip["c_d"]) for ip in o["ipams"])
        raise KeyError(term)


@pytest.fixture(scope="module", params=DEVICES)
def device(request):
    return request.param


@pytest.fixture
def ctrl_c_in_round_1(monkeypatch):
    """The designer's second control call (design round 1) raises KeyboardInterrupt, as Ctrl-C would."""
    import warp_shape.designer.loop as designer_loop

    real, calls = designer_loop.control_many, {"n": 0}

    def interrupt_second_round(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(designer_loop, "control_many", interrupt_second_round)
