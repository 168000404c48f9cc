"""A vectorized NumPy (float64) implementation of the membrane model, for benchmarks and cross-checks.

Same physics as the Warp kernels (SPEC section 4): edge springs with dampers, exact (or paper eq. 9)
bending, pressure from the enclosed air, IPAMs as three sub-springs, viscous damping, jammed
stiffness and rest values; classical RK4 and semi-implicit Euler with controls held over a step.
It is written to be a fair, fast NumPy baseline: structure-of-arrays layout ((3, n) coordinates),
one gather per element family and one ``np.bincount`` per coordinate for every scatter. It does not
estimate stable steps or detect blow-ups; it is not part of the public simulation API.

    nm = NumpyMembrane.from_simulator(sim)        # copy state, jam values, controls and internal step
    nm.step(20); nm.positions                     # (V, 3) float64
"""

from __future__ import annotations

import numpy as np

from warp_shape.display import Design
from warp_shape.errors import DesignError
from warp_shape.material import GAS_CONSTANT
from warp_shape.model import host_model
from warp_shape.physics.ipam_law import natural_length_np

__all__ = ["NumpyMembrane"]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of (3, n) arrays."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


class NumpyMembrane:
    """One world of a design in float64 NumPy: state, controls, jamming, forces and time stepping.

    ``h`` is the internal step (s); ``step(n)`` advances n internal steps.
    """

    def __init__(self, design: Design, integrator: str = "rk4", h: float = 1e-4, bending: str = "exact"):
        if not isinstance(design, Design):
            raise DesignError(f"NumpyMembrane needs a ws.Design, got {type(design).__name__}")
        key = integrator.lower().replace("-", "_")
        if key not in ("rk4", "semi_implicit"):
            raise DesignError(f"unknown integrator {integrator!r}; choose 'rk4' or 'semi_implicit'")
        if bending not in ("exact", "paper"):
            raise DesignError(f"bending must be 'exact' or 'paper', got {bending!r}")
        self.design = design
        self.integrator = key
        self.h = float(h)
        self.paper = bending == "paper"
        mat = design.material
        host = host_model(design)
        self.host = host
        self.V = design.rest.n_vertices
        hinges, faces = host.hinges, host.faces
        self._h = [np.ascontiguousarray(hinges[:, k]) for k in range(4)]
        self._f = [np.ascontiguousarray(faces[:, k]) for k in range(3)]
        self.k_edge = host.edge_stiffness
        self.c_s, self.c_v = mat.spring_damping, mat.viscous_damping
        self.k_t = mat.bending_stiffness
        self.jam_stretch, self.jam_bend = mat.jam_stretch_factor, mat.jam_bend_factor
        self.gas_rt, self.p_atm = GAS_CONSTANT * mat.temperature, mat.atmospheric_pressure
        self.inv_mass = 1.0 / host.mass
        self.n_ipams = design.n_ipams
        if self.n_ipams:
            pairs = host.ipam_sub_pairs
            self._pa, self._pb = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
            self.k_sub = np.repeat(host.ipam_stiffness / 3.0, 3)
            self.c_sub = np.repeat(host.ipam_damping, 3)
            self.sub_offsets = host.ipam_sub_offsets
        # one scatter for every family: hinge vertices, face vertices, IPAM ends
        idx = list(self._h) + list(self._f) + ([self._pa, self._pb] if self.n_ipams else [])
        self._scatter_index = np.concatenate(idx)
        # state (structure of arrays), jam values and controls
        self._x = np.ascontiguousarray(host.rest_vertices.T, dtype=np.float64)
        self._v = np.zeros_like(self._x)
        self.rest_length = host.rest_length.copy()
        self.rest_angle = host.rest_angle.copy()
        self.edge_jammed = np.zeros(hinges.shape[0], dtype=bool)
        self.cell_jammed = np.zeros(design.n_cells, dtype=bool)
        self.air_moles = self.p_atm * design.rest.volume() / self.gas_rt
        self.ipam_pressures = np.zeros(self.n_ipams)
        self._update_stiffness()

    # ------------------------------------------------------------------ construction from a simulator
    @classmethod
    def from_simulator(cls, sim, world: int = 0) -> "NumpyMembrane":
        """Copy a Simulator's state, jam values, controls and internal step (one world)."""
        nm = cls(sim.design, integrator=sim.integrator, h=sim.internal_dt, bending=sim.bending)
        st = sim.state
        nm.positions = st.x.numpy()[world].astype(np.float64)
        nm.velocities = st.v.numpy()[world].astype(np.float64)
        nm.rest_length = st.rest_length.numpy()[world].astype(np.float64)
        nm.rest_angle = st.rest_angle.numpy()[world].astype(np.float64)
        nm.edge_jammed = st.jammed.numpy()[world].astype(bool)
        nm.cell_jammed = st.cell_jammed[world].copy()
        nm.air_moles = float(sim.control.air.numpy()[world])
        nm.ipam_pressures = sim.control.ipam_pressure.numpy()[world, : nm.n_ipams].copy()
        nm._update_stiffness()
        return nm

    # ------------------------------------------------------------------ state
    @property
    def positions(self) -> np.ndarray:
        return self._x.T.copy()

    @positions.setter
    def positions(self, value):
        self._x = np.ascontiguousarray(np.asarray(value, dtype=np.float64).T)

    @property
    def velocities(self) -> np.ndarray:
        return self._v.T.copy()

    @velocities.setter
    def velocities(self, value):
        self._v = np.ascontiguousarray(np.asarray(value, dtype=np.float64).T)

    def _update_stiffness(self):
        self.k_eff = self.k_edge * np.where(self.edge_jammed, self.jam_stretch, 1.0)
        self.kt_eff = self.k_t * np.where(self.edge_jammed, self.jam_bend, 1.0)

    def jam(self, cell: int) -> None:
        """Freeze the cell's edges at their current length and angle; x10 / x30 stiffness (once)."""
        if self.cell_jammed[cell]:
            return
        edges = self.host.cell_edges[cell]
        edges = edges[~self.edge_jammed[edges]]
        x = self._x
        h0, h1, h2, h3 = (hk[edges] for hk in self._h)
        e = x[:, h1] - x[:, h0]
        n_a = _cross(e, x[:, h2] - x[:, h0])
        n_b = _cross(x[:, h0] - x[:, h1], x[:, h3] - x[:, h1])
        length = np.sqrt(_dot(e, e))
        self.rest_length[edges] = length
        self.rest_angle[edges] = np.arctan2(_dot(_cross(n_a, n_b), e), _dot(n_a, n_b) * length)
        self.edge_jammed[edges] = True
        self.cell_jammed[cell] = True
        self._update_stiffness()

    # ------------------------------------------------------------------ physics
    def volume(self, x: np.ndarray | None = None) -> float:
        """Enclosed volume in m^3."""
        x = self._x if x is None else x
        f0, f1, f2 = (x[:, fk] for fk in self._f)
        return float(np.sum(_dot(f0, _cross(f1, f2)))) / 6.0

    def pressure(self) -> float:
        """Gauge pressure n R T / V - p_atm in Pa."""
        return self.air_moles * self.gas_rt / self.volume() - self.p_atm

    def _forces_soa(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Total force (3, V) at (x, v) in structure-of-arrays layout."""
        h0, h1, h2, h3 = self._h
        x0, x1, x2, x3 = x[:, h0], x[:, h1], x[:, h2], x[:, h3]
        e = x1 - x0
        ee = _dot(e, e)
        length = np.sqrt(ee)
        dhat = e / length
        s = self.k_eff * (length - self.rest_length) + self.c_s * _dot(v[:, h1] - v[:, h0], dhat)
        fs = dhat * s
        parts = []
        if self.k_t > 0.0:
            n_a = _cross(e, x2 - x0)
            n_b = _cross(x0 - x1, x3 - x1)
            theta = np.arctan2(_dot(_cross(n_a, n_b), e), _dot(n_a, n_b) * length)
            torque_l = -self.kt_eff * (theta - self.rest_angle) * length
            f2 = n_a * (-torque_l / _dot(n_a, n_a))
            f3 = n_b * (-torque_l / _dot(n_b, n_b))
            if self.paper:
                fe = -0.5 * (f2 + f3)
                f0, f1 = fs + fe, fe - fs
            else:
                t2 = _dot(x2 - x0, e) / ee
                t3 = _dot(x3 - x0, e) / ee
                f1 = -fs - (f2 * t2 + f3 * t3)
                f0 = fs - (f2 * (1.0 - t2) + f3 * (1.0 - t3))
            parts += [f0, f1, f2, f3]
        else:
            zero = np.zeros_like(fs)
            parts += [fs, -fs, zero, zero]
        # pressure: p dV/dx, each face pushing its vertices by p area / 3 n_hat
        xf0, xf1, xf2 = (x[:, fk] for fk in self._f)
        n2a = _cross(xf1 - xf0, xf2 - xf0)
        vol = float(np.sum(_dot(xf0, n2a))) / 6.0
        p = self.air_moles * self.gas_rt / vol - self.p_atm
        fp = n2a * (p / 6.0)
        parts += [fp, fp, fp]
        if self.n_ipams:
            pa, pb = self._pa, self._pb
            d = x[:, pb] - x[:, pa]
            dl = np.sqrt(_dot(d, d))
            dh = d / dl
            natural = natural_length_np(self.host.ipam_free_length, self.host.ipam_area_over_k, self.ipam_pressures)
            natural = np.repeat(natural, 3) + self.sub_offsets
            fi = dh * (self.k_sub * (dl - natural) + self.c_sub * _dot(v[:, pb] - v[:, pa], dh))
            parts += [fi, -fi]
        vals = np.concatenate(parts, axis=1)
        idx = self._scatter_index
        f = np.stack([np.bincount(idx, weights=vals[c], minlength=self.V) for c in range(3)])
        f -= self.c_v * v
        return f

    def forces(self) -> np.ndarray:
        """(V, 3) total force at the current state (N)."""
        return self._forces_soa(self._x, self._v).T.copy()

    def energy(self) -> dict:
        """Mechanical energy terms (J), same definitions as Simulator.energy()."""
        x, v = self._x, self._v
        h0, h1, h2, h3 = self._h
        kinetic = 0.5 * float(np.sum(self.host.mass * _dot(v, v)))
        e = x[:, h1] - x[:, h0]
        length = np.sqrt(_dot(e, e))
        spring = 0.5 * float(np.sum(self.k_eff * (length - self.rest_length) ** 2))
        n_a = _cross(e, x[:, h2] - x[:, h0])
        n_b = _cross(x[:, h0] - x[:, h1], x[:, h3] - x[:, h1])
        theta = np.arctan2(_dot(_cross(n_a, n_b), e), _dot(n_a, n_b) * length)
        bending = 0.5 * float(np.sum(self.kt_eff * (theta - self.rest_angle) ** 2))
        vol = self.volume()
        gas = self.p_atm * vol - self.air_moles * self.gas_rt * np.log(vol)
        ipam = 0.0
        if self.n_ipams:
            d = x[:, self._pb] - x[:, self._pa]
            natural = natural_length_np(self.host.ipam_free_length, self.host.ipam_area_over_k, self.ipam_pressures)
            natural = np.repeat(natural, 3) + self.sub_offsets
            ipam = 0.5 * float(np.sum(self.k_sub * (np.sqrt(_dot(d, d)) - natural) ** 2))
        out = dict(kinetic=kinetic, spring=spring, bending=bending, gas=gas, ipam=ipam)
        out["total"] = sum(out.values())
        return out

    # ------------------------------------------------------------------ stepping
    def step(self, n: int = 1) -> None:
        """Advance n internal steps of h."""
        h = self.h
        inv_m = self.inv_mass
        for _ in range(int(n)):
            x, v = self._x, self._v
            if self.integrator == "semi_implicit":
                v = v + self._forces_soa(x, v) * (h * inv_m)
                self._v = v
                self._x = x + v * h
                continue
            a1 = self._forces_soa(x, v) * inv_m
            x2, v2 = x + (0.5 * h) * v, v + (0.5 * h) * a1
            a2 = self._forces_soa(x2, v2) * inv_m
            x3, v3 = x + (0.5 * h) * v2, v + (0.5 * h) * a2
            a3 = self._forces_soa(x3, v3) * inv_m
            x4, v4 = x + h * v3, v + h * a3
            a4 = self._forces_soa(x4, v4) * inv_m
            self._x = x + (h / 6.0) * (v + 2.0 * v2 + 2.0 * v3 + v4)
            self._v = v + (h / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
