"""The public simulation API: ``ws.Simulator(design, ...)``.

``dt`` is the output (control) step. By default each output step is split into the fewest equal
internal steps that respect the model's stable-step estimate (``sim.substeps``); the estimate is
re-evaluated when air is changed, a cell jams or positions are set, and every
``reestimate_every`` internal steps (default 1000; each costs milliseconds of host work). With
``substeps`` fixed by the user, an internal step beyond the estimate is refused with a
``StabilityError`` naming a safe dt. A blow-up (non-finite or runaway positions or speeds) raises
``SimulationError`` naming the step, the quantity and a safe dt.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from warp_shape.kernels import common as kc
from warp_shape.kernels import jamming as kj
from warp_shape.kernels import pressure as kp

from .design import Design
from .errors import DesignError, SimulationError, StabilityError
from .material import GAS_CONSTANT
from .model import Control, State, build_model, dihedral_angles_np, volumes_np
from .solver import (FORCE_TERMS, elastic_omega2_bound, eval_forces, eval_forces_fused, make_solver,
                     stable_dt_estimate, substeps_for)

__all__ = ["Simulator"]

_BLOWUP = {4: "positions became non-finite", 3: "velocities became non-finite",
           2: "positions ran away (a vertex left the region around the device)",
           1: "speeds ran away (a vertex crossed the device in one internal step)"}
LAUNCH_MODES = ("graph", "record", "direct")


def _check_device(device) -> str:
    try:
        return str(wp.get_device(device))
    except Exception as exc:
        have = ", ".join(str(d) for d in wp.get_devices())
        raise DesignError(f"device {device!r} is not available ({exc}); devices here: {have}") from None


class Simulator:
    """Simulate a design: positions, velocities, air, IPAM pressures, jamming, stepping.

    ``worlds`` > 1 runs that many independent copies of the design in one batch (one launch per
    kernel); array properties then carry a leading world axis.
    """

    def __init__(self, design: Design, device: str = "cpu", integrator: str = "rk4", dt: float = 1e-3,
                 precision: str = "float32", bending: str = "exact", substeps: int | None = None,
                 worlds: int = 1, launch_mode: str = "graph", reestimate_every: int = 1000):
        if not isinstance(design, Design):
            raise DesignError(f"Simulator needs a ws.Design, got {type(design).__name__}")
        if bending not in ("exact", "paper"):
            raise DesignError(f"bending must be 'exact' or 'paper', got {bending!r}")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise DesignError(f"dt must be a positive number of seconds, got {dt!r}")
        if substeps is not None and (not isinstance(substeps, (int, np.integer)) or substeps < 1):
            raise DesignError(f"substeps must be None (automatic) or an integer >= 1, got {substeps!r}")
        if not isinstance(worlds, (int, np.integer)) or worlds < 1:
            raise DesignError(f"worlds must be an integer >= 1, got {worlds!r}")
        if launch_mode not in LAUNCH_MODES:
            raise DesignError(f"launch_mode must be one of {LAUNCH_MODES}, got {launch_mode!r}")
        wp.init()
        self.device = _check_device(device)
        self.design = design
        self.dt = float(dt)
        self.bending = bending
        self.worlds = int(worlds)
        self.launch_mode = launch_mode
        self.reestimate_every = int(reestimate_every)
        self._fixed_substeps = None if substeps is None else int(substeps)
        self.model = build_model(design, self.device, precision)
        self.precision = precision
        self.state = State(self.model, self.worlds)
        m = self.model
        self._rest_volume = design.rest.volume()
        air0 = m.atmospheric_pressure * self._rest_volume / (GAS_CONSTANT * m.temperature)
        self.control = Control(m, self.worlds, air0)
        self.solver = make_solver(integrator, m, self.state, self.control, paper_bending=(bending == "paper"))
        self.integrator = self.solver.name
        # probe buffers for read-outs outside the step loop
        self._fg_probe = wp.zeros_like(self.solver.fg)  # (2, W, V) forces, dV/dx
        self._f_probe = self._fg_probe[0]
        self._vol_probe = wp.zeros(self.worlds, dtype=wp.float64, device=self.device)
        self._vol2_probe = wp.zeros((self.worlds, 1), dtype=wp.float64, device=self.device)
        # blow-up codes written by the step's last kernel; on CPU the host reads them in place
        self._status = self.solver.status
        self._status_host = self._status.numpy() if self._status.device.is_cpu else None
        self._edge_len = wp.zeros((self.worlds, m.n_edges), dtype=m.scalar, device=self.device)
        self._edge_ang = wp.zeros((self.worlds, m.n_edges), dtype=m.scalar, device=self.device)
        # stepping plan
        self._h = None
        self._substeps = None
        self._dt_stable = None
        self._plan = None  # recorded launches or a captured graph of one internal step
        self.step_kernels: list[str] = []  # kernel names launched by one internal step
        self._dirty = True
        self._geometry_version = 0  # bumped when positions are set (invalidates the cached elastic bound)
        self._elastic_cache = None
        self._internal_steps = 0  # internal steps taken
        self._estimated_at = 0  # internal step count at the last periodic re-estimate (keys the elastic bound)
        self.step_count = 0
        self.time = 0.0
        self._update_plan()

    # ------------------------------------------------------------------ world helpers
    def _out(self, a: np.ndarray):
        return a[0] if self.worlds == 1 else a

    def _per_world(self, value, shape_tail: tuple, name: str) -> np.ndarray:
        a = np.asarray(value, dtype=np.float64)
        full = (self.worlds,) + shape_tail
        if a.shape == shape_tail:
            a = np.broadcast_to(a, full)
        if a.shape != full:
            raise DesignError(f"{name} must have shape {shape_tail} or {full}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise DesignError(f"{name} must be finite; got non-finite values")
        return np.ascontiguousarray(a)

    # ------------------------------------------------------------------ state access
    @property
    def positions(self) -> np.ndarray:
        """(V, 3) float64 positions in m ((W, V, 3) with several worlds)."""
        return self._out(self.state.x.numpy().astype(np.float64))

    @positions.setter
    def positions(self, value):
        a = self._per_world(value, (self.model.n_vertices, 3), "positions")
        self.state.x.assign(a.astype(self.model.np_dtype))
        self._geometry_version += 1
        self._dirty = True

    @property
    def velocities(self) -> np.ndarray:
        """(V, 3) float64 velocities in m/s ((W, V, 3) with several worlds)."""
        return self._out(self.state.v.numpy().astype(np.float64))

    @velocities.setter
    def velocities(self, value):
        a = self._per_world(value, (self.model.n_vertices, 3), "velocities")
        self.state.v.assign(a.astype(self.model.np_dtype))

    @property
    def air_moles(self):
        """Chamber air amount n in mol (float; (W,) with several worlds)."""
        a = self.control.air.numpy().copy()
        return float(a[0]) if self.worlds == 1 else a

    @air_moles.setter
    def air_moles(self, value):
        a = self._per_world(value, (), "air_moles")
        if np.any(a < 0):
            raise DesignError(f"air_moles must be >= 0 mol, got {a.min()}")
        self.control.air.assign(a)
        self._dirty = True

    @property
    def ipam_pressures(self) -> np.ndarray:
        """(n_ipam,) IPAM gauge pressures in Pa ((W, n_ipam) with several worlds)."""
        a = self.control.ipam_pressure.numpy()[:, : self.model.n_ipams].copy()
        return self._out(a)

    @ipam_pressures.setter
    def ipam_pressures(self, value):
        n = self.model.n_ipams
        if n == 0:
            raise DesignError("this design has no IPAMs; add one with Design.add_ipam before setting pressures")
        a = self._per_world(value, (n,), "ipam_pressures")
        lim = self.model.host.ipam_limits
        low, high = a < lim[:, 0] - 1e-9, a > lim[:, 1] + 1e-9
        if np.any(low | high):
            w, i = np.argwhere(low | high)[0]
            raise DesignError(
                f"IPAM {i} pressure {a[w, i]:.6g} Pa is outside its limits [{lim[i, 0]:.6g}, {lim[i, 1]:.6g}] Pa; "
                f"clip it or widen pressure_limits in Design.add_ipam")
        self.control.ipam_pressure.assign(a)

    @property
    def jammed(self) -> np.ndarray:
        """(n_cell,) bool jam state of each cell ((W, n_cell) with several worlds)."""
        return self._out(self.state.cell_jammed.copy())

    @property
    def jam_times(self) -> np.ndarray:
        """(n_cell,) simulated time at which each cell jammed (NaN if not jammed)."""
        return self._out(self.state.cell_jam_time.copy())

    def jam(self, cell: int, world: int | None = None) -> None:
        """Jam a cell (once; a jammed cell never unjams). ``world`` None jams it in every world."""
        m = self.model
        if isinstance(cell, (bool, np.bool_)) or not isinstance(cell, (int, np.integer)) or not 0 <= cell < m.n_cells:
            raise DesignError(f"cell must be an index in 0..{m.n_cells - 1}, got {cell!r}")
        mask = np.zeros(self.worlds, dtype=np.int32)
        worlds = range(self.worlds) if world is None else [int(world)]
        for w in worlds:
            if not 0 <= w < self.worlds:
                raise DesignError(f"world must be in 0..{self.worlds - 1}, got {w}")
            if not self.state.cell_jammed[w, cell]:
                mask[w] = 1
        if not mask.any():
            return
        edges = m.cell_edges[cell]
        st = self.state
        wp.launch(kj.jam_edges_kernel, (self.worlds, edges.shape[0]),
                  [m.hinges, edges, wp.array(mask, dtype=wp.int32, device=self.device),
                   m.scalar(m.jam_stretch_factor), m.scalar(m.jam_bend_factor), st.x, st.edge, st.jammed],
                  device=self.device)
        st.cell_jammed[mask.astype(bool), cell] = True
        st.cell_jam_time[mask.astype(bool), cell] = self.time
        self._dirty = True

    # ------------------------------------------------------------------ read-outs
    def _direct(self, kernel, dim, inputs):
        wp.launch(kernel, dim, inputs, device=self.device)

    def forces(self, term: str | None = None) -> np.ndarray:
        """Total force on every vertex (N), all terms and damping included; or one term of
        ``FORCE_TERMS`` ('spring' (with its dampers), 'bending', 'pressure', 'ipam', 'viscous')."""
        terms = FORCE_TERMS
        if term is not None:
            if term not in FORCE_TERMS:
                raise DesignError(f"unknown force term {term!r}; choose one of {FORCE_TERMS}")
            terms = (term,)
        st = self.state
        if term is None:  # the total goes through the same fused kernels as a step
            eval_forces_fused(self.model, st, self.control, self._fg_probe, self._vol2_probe, self._direct,
                              paper_bending=(self.bending == "paper"))
        else:
            eval_forces(self.model, st, self.control, st.x, st.v, self._f_probe, self._vol_probe, self._direct,
                        paper_bending=(self.bending == "paper"), terms=terms)
        return self._out(self._f_probe.numpy().astype(np.float64))

    def _volumes(self) -> np.ndarray:
        self._vol_probe.zero_()
        self._direct(kp.eval_volume_kernel, (self.worlds, self.model.n_faces),
                     [self.model.faces, self.state.x, self._vol_probe])
        return self._vol_probe.numpy().copy()

    def volume(self):
        """Enclosed volume in m^3 (float; (W,) with several worlds)."""
        v = self._volumes()
        return float(v[0]) if self.worlds == 1 else v

    def pressure(self):
        """Chamber gauge pressure n R T / V - p_atm in Pa."""
        m = self.model
        p = self.control.air.numpy() * m.gas_rt / self._volumes() - m.atmospheric_pressure
        return float(p[0]) if self.worlds == 1 else p

    def _ipam_geometry(self):
        h = self.model.host
        x = self.state.x.numpy().astype(np.float64)
        fa, fb = h.faces[h.ipam_faces[:, 0]], h.faces[h.ipam_faces[:, 1]]
        length = np.linalg.norm(x[:, fb].mean(axis=2) - x[:, fa].mean(axis=2), axis=-1)  # (W, n_ipam)
        p = self.control.ipam_pressure.numpy()[:, : self.model.n_ipams]
        natural = h.ipam_free_length + h.ipam_area_over_k * p
        return length, natural

    def ipam_lengths(self) -> np.ndarray:
        """(n_ipam,) distance between the centroids of each IPAM's end faces (m)."""
        if self.model.n_ipams == 0:
            return self._out(np.zeros((self.worlds, 0)))
        return self._out(self._ipam_geometry()[0])

    def ipam_forces(self) -> np.ndarray:
        """(n_ipam,) axial force k (L - L_n) in N, positive = tension."""
        if self.model.n_ipams == 0:
            return self._out(np.zeros((self.worlds, 0)))
        length, natural = self._ipam_geometry()
        return self._out(self.model.host.ipam_stiffness * (length - natural))

    def edge_state(self):
        """Current (lengths, dihedral angles) of every edge, each (E,) (or (W, E))."""
        self._direct(kc.edge_state_kernel, (self.worlds, self.model.n_edges),
                     [self.model.hinges, self.state.x, self._edge_len, self._edge_ang])
        return self._out(self._edge_len.numpy().astype(np.float64)), self._out(self._edge_ang.numpy().astype(np.float64))

    def energy(self) -> dict:
        """Mechanical energy terms in J (float64, host): kinetic, spring, bending, gas, ipam, total.

        Gas energy is p_atm V - n R T ln V (its negative gradient is the pressure force); the
        total is conserved by the undamped dynamics with fixed air and IPAM pressures.
        """
        m, h, st = self.model, self.model.host, self.state
        x = st.x.numpy().astype(np.float64)
        v = st.v.numpy().astype(np.float64)
        jam = st.jammed.numpy().astype(bool)
        hinges = h.hinges
        kinetic = 0.5 * np.einsum("v,wvi,wvi->w", h.mass, v, v)
        length = np.linalg.norm(x[:, hinges[:, 1]] - x[:, hinges[:, 0]], axis=-1)
        k = h.edge_stiffness * np.where(jam, m.jam_stretch_factor, 1.0)
        spring = 0.5 * np.sum(k * (length - st.rest_length.numpy()) ** 2, axis=1)
        bend = np.zeros(self.worlds)
        if m.has_bending:
            kt = m.bending_stiffness * np.where(jam, m.jam_bend_factor, 1.0)
            theta = dihedral_angles_np(x, hinges)
            bend = 0.5 * np.sum(kt * (theta - st.rest_angle.numpy()) ** 2, axis=1)
        vol = volumes_np(x, h.faces)
        air = self.control.air.numpy()
        gas = m.atmospheric_pressure * vol - air * m.gas_rt * np.log(vol)
        ipam = np.zeros(self.worlds)
        if m.has_ipams:
            pairs = h.ipam_sub_pairs
            p = self.control.ipam_pressure.numpy()[:, : m.n_ipams]
            natural = np.repeat(h.ipam_free_length + h.ipam_area_over_k * p, 3, axis=1) + h.ipam_sub_offsets
            d = np.linalg.norm(x[:, pairs[:, 1]] - x[:, pairs[:, 0]], axis=-1)
            ipam = 0.5 * np.sum(np.repeat(h.ipam_stiffness / 3.0, 3) * (d - natural) ** 2, axis=1)
        out = dict(kinetic=kinetic, spring=spring, bending=bend, gas=gas, ipam=ipam)
        out["total"] = sum(out.values())
        return {key: (float(val[0]) if self.worlds == 1 else val) for key, val in out.items()}

    # ------------------------------------------------------------------ stepping
    def stable_dt(self) -> float:
        """Current conservative stable internal step (s), the minimum over worlds.

        The elastic part of the bound (a short Lanczos run, see solver.elastic_omega2_bound) is
        cached until a cell jams, positions are set or ``reestimate_every`` internal steps pass; air
        changes only re-evaluate the cheap pressure and gas terms."""
        m, st = self.model, self.state
        edge_jam = st.jammed.numpy().astype(bool)
        x = st.x.numpy().astype(np.float64)
        rest = st.rest_length.numpy().astype(np.float64)
        key = (self._geometry_version, int(edge_jam.sum()), self._estimated_at)
        if self._elastic_cache is None or self._elastic_cache[0] != key:
            self._elastic_cache = (key, elastic_omega2_bound(m, edge_jam, x, rest))
        est = stable_dt_estimate(m, type(self.solver), edge_jam, self.control.air.numpy(), x, rest,
                                 elastic_bound=self._elastic_cache[1])
        return float(est.min())

    @property
    def substeps(self) -> int:
        """Internal steps per output step dt."""
        if self._dirty:
            self._update_plan()
        return self._substeps

    @property
    def internal_dt(self) -> float:
        """Internal step dt / substeps in s."""
        return self.dt / self.substeps

    def _update_plan(self):
        self._dt_stable = self.stable_dt()
        if self._fixed_substeps is None:
            n = substeps_for(self.dt, self._dt_stable)
        else:
            n = self._fixed_substeps
            h = self.dt / n
            if h > self._dt_stable:
                safe = self._dt_stable * n
                raise StabilityError(
                    f"internal step dt/substeps = {h:.4g} s is beyond the stable step estimate "
                    f"{self._dt_stable:.4g} s of this model ({self.integrator}, current stiffness and pressure); "
                    f"use dt <= {safe:.4g} s with substeps={n}, substeps >= {substeps_for(self.dt, self._dt_stable)}, "
                    f"or substeps=None to choose automatically")
        h = self.dt / n
        self._substeps = n
        if h != self._h or self._plan is None:
            self._h = h
            self._build_plan(h)
        self._dirty = False

    def _build_plan(self, h: float):
        names: list[str] = []
        cmds: list = []

        def record(kernel, dim, inputs):
            names.append(kernel.key)
            cmds.append(wp.launch(kernel, dim, inputs, device=self.device, record_cmd=True))

        self.solver.step(h, record)
        self.step_kernels = names
        self._plan = ("record", cmds)
        if self.launch_mode == "direct":
            self._plan = ("direct", None)
        elif self.launch_mode == "graph":
            try:
                with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                    for cmd in cmds:
                        cmd.launch()
                self._plan = ("graph", capture.graph)
            except Exception:  # capture unsupported here: recorded launches are the next best
                self._plan = ("record", cmds)

    def _run_internal(self, count: int):
        kind, plan = self._plan
        if kind == "graph":
            for _ in range(count):
                wp.capture_launch(plan)
        elif kind == "record":
            for _ in range(count):
                for cmd in plan:
                    cmd.launch()
        else:
            for _ in range(count):
                self.solver.step(self._h, self._direct)

    def _check(self):
        # the step kernels flag blow-ups; status stays zero until one (zeroed again once reported)
        status = self._status_host if self._status_host is not None else self._status.numpy()
        if status.any():
            status = status.copy()
            self._status.zero_()
            w = int(np.argmax(status))
            safe = 0.5 * min(self._dt_stable, self._h)
            raise SimulationError(
                f"simulation blew up at output step {self.step_count} (t = {self.time:.6g} s, world {w}): "
                f"{_BLOWUP[int(status[w])]} with internal step {self._h:.4g} s; stable estimate "
                f"{self._dt_stable:.4g} s. Try a smaller step, e.g. dt = {safe:.3g} s with substeps=1, "
                f"or check the inputs (air, pressures, stiffness) for extreme values",
                step=self.step_count, quantity=_BLOWUP[int(status[w])].split(" ")[0], safe_dt=safe, world=w)

    def step(self, n: int = 1) -> None:
        """Advance n output steps of dt (each ``substeps`` internal steps), checking for blow-up."""
        if not isinstance(n, (int, np.integer)) or n < 0:
            raise DesignError(f"step count must be an integer >= 0, got {n!r}")
        for _ in range(int(n)):
            if self.reestimate_every and self._internal_steps - self._estimated_at >= self.reestimate_every:
                self._estimated_at = self._internal_steps
                self._dirty = True
            if self._dirty:
                self._update_plan()
            self._run_internal(self._substeps)
            self._internal_steps += self._substeps
            self.step_count += 1
            self.time += self.dt
            self._check()

    def __repr__(self) -> str:
        return (f"Simulator({self.design!r}, device={self.device!r}, integrator={self.integrator!r}, dt={self.dt}, "
                f"precision={self.precision!r}, worlds={self.worlds})")
