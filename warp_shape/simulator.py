"""The public simulation API: ``ws.Simulator(design, ...)`` holds a design's state and steps it.

``dt`` is the output (control) step. By default each output step is split into the fewest equal
internal steps that respect the model's stable-step estimate (``sim.substeps``); the estimate is
re-evaluated when air is changed, a cell jams or positions are set, and every
``reestimate_every`` internal steps (default 1000; each costs milliseconds of host work). With
``substeps`` fixed by the user, an internal step beyond the estimate is refused with a
``StabilityError`` naming a safe dt. A blow-up (non-finite or runaway positions or speeds) raises
``SimulationError`` naming the step, the quantity and a safe dt.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import warp as wp

from warp_shape.kernels import common as kc

from .display import Design
from .static_settle import MAX_ITERATIONS, STATUS_NAMES, Equilibrium, StaticSettle
from .errors import DesignError, SimulationError
from .forces import eval_forces, eval_forces_fused, force_terms
from .integrators import BlowupWatch, blowup_error, make_solver
from .crossing import check_rest_mesh, inward_fraction, self_crossing
from .model import State, WorldRef, build_model, check_device, check_layout, copy_worlds, host_model
from .physics.bending import bending_energy_np
from .physics.ipam_law import axial_force_np, ipam_lengths_np, natural_length_np
from .physics.jamming import eval_jam, jammed_factor_np
from .physics.pressure import eval_volume, gas_energy_np, gauge_pressure_np, pressure_rows, volumes_np
from .physics.springs import spring_energy_np
from .simulation_settings import SimulationSettings
from .errors import numeric_array
from .stability import (check_chamber, check_fixed_step, check_stable_dt, check_storable, elastic_omega2_bound,
                        jam_rows, stable_dt_estimate, substeps_error, substeps_for, worlds_identical)
from .step_plan import Checkpoint, StepPlan

__all__ = ["Simulator", "FROM_SETTINGS", "MAX_REFINE", "TANGLE_EVERY", "TANGLE_MIN_INTERNAL"]

#: most automatic-substep refinement after blow-ups within the estimate (see Simulator._retry)
MAX_REFINE = 8
#: output steps between two checks that the membrane does not pass through itself (see check_tangle)
TANGLE_EVERY = 10
#: and at least this many internal steps apart, so that a check's host work (about 0.1 ms at 642
#: vertices) stays a few per cent of the stepping even at one internal step per output step
TANGLE_MIN_INTERNAL = 50
#: faces facing the membrane's centre (fraction) beyond which a world is tested exactly for a self-crossing
INWARD_FACES = 0.01

class _FromSettings:
    def __repr__(self) -> str:
        return "<from settings>"


#: default of the Simulator's simulation keywords: the value of ``settings`` (SimulationSettings' default)
FROM_SETTINGS = _FromSettings()


class Simulator:
    """Simulate a design: positions, velocities, air, IPAM pressures, jamming, stepping.

    The simulation options come from ``settings`` (a ``SimulationSettings``; its defaults when None:
    integrator "rk4", dt 1e-3 s, precision "float32", bending "exact", automatic substeps, launch mode
    "graph", re-estimate every 1000 internal steps, settle "static"); each keyword given explicitly overrides the
    matching setting. ``worlds`` > 1 runs that many independent copies of the design in one batch
    (one launch per kernel); array properties then carry a leading world axis.
    """

    def __init__(self, design: Design, device: str = "cpu", integrator: str = FROM_SETTINGS,
                 dt: float = FROM_SETTINGS, precision: str = FROM_SETTINGS, bending: str = FROM_SETTINGS,
                 substeps: int | None = FROM_SETTINGS, worlds: int = 1, launch_mode: str = FROM_SETTINGS,
                 reestimate_every: int = FROM_SETTINGS, settings: SimulationSettings | None = None,
                 max_substeps: int = FROM_SETTINGS, settle: str = FROM_SETTINGS):
        if not isinstance(design, Design):
            raise DesignError(f"Simulator needs a ws.Design, got {type(design).__name__}")
        if settings is not None and not isinstance(settings, SimulationSettings):
            raise DesignError(f"settings must be a SimulationSettings or None, got {type(settings).__name__}")
        check_rest_mesh(design.rest)
        given = dict(integrator=integrator, dt=dt, precision=precision, bending=bending, substeps=substeps,
                     launch_mode=launch_mode, reestimate_every=reestimate_every, max_substeps=max_substeps,
                     settle=settle)
        self.settings = (settings or SimulationSettings()).replace(
            **{k: v for k, v in given.items() if v is not FROM_SETTINGS})
        if isinstance(worlds, (bool, np.bool_)) or not isinstance(worlds, (int, np.integer)) or worlds < 1:
            raise DesignError(f"worlds must be an integer >= 1, got {worlds!r}")
        wp.init()
        s = self.settings
        self.device = check_device(device)
        self.design = design
        self.dt, self.bending, self.precision = s.dt, s.bending, s.precision
        self.launch_mode, self.reestimate_every = s.launch_mode, s.reestimate_every
        self.worlds = int(worlds)
        host = host_model(design)  # built once: checked, then copied to the device
        check_storable(host, design.material, s.precision)
        self.model = m = build_model(design, self.device, s.precision, host=host)
        try:  # two states: each internal step goes from one into the other (self.plan.parity: the current)
            first = m.state(self.worlds)
            self._states = (first, m.state(self.worlds, jam_from=first))
            self.control = m.control(self.worlds)
        except (MemoryError, ValueError, RuntimeError) as exc:  # arrays too large to allocate
            raise DesignError(f"worlds = {self.worlds} copies of a {m.n_vertices}-vertex design do not fit in "
                              f"memory ({exc}); use fewer worlds") from None
        self.solver = make_solver(s.integrator, m, self.worlds, paper_bending=(s.bending == "paper"))
        self.integrator = self.solver.name
        # probe buffers for read-outs outside the step loop
        self._fg_probe = wp.zeros_like(self.solver.fg)  # (2, W, V) forces, dV/dx
        self._vol_probe = wp.zeros(self.worlds, dtype=wp.float64, device=self.device)  # (W,)
        self._vol2_probe = wp.zeros((self.worlds, 1), dtype=wp.float64, device=self.device)  # (W, 1)
        self._edge_len = wp.zeros((self.worlds, m.n_edges), dtype=m.scalar, device=self.device)  # (W, E)
        self._edge_ang = wp.zeros((self.worlds, m.n_edges), dtype=m.scalar, device=self.device)  # (W, E)
        # blow-up codes written by the step's last kernel: read in place on CPU, noted on a GPU
        # device and copied only where the host waits anyway (BlowupWatch)
        self.blowup_watch = BlowupWatch(self.solver.status)
        # stepping: the plan of one internal step, rebuilt when the stable estimate changes the step
        self.plan = StepPlan(self.device, s.launch_mode)  # before the first use of self.state
        self._substeps = None
        self._dt_stable = None
        self._dirty = True
        self._geometry_version = 0  # bumped when positions are set (invalidates the cached elastic bound)
        self._elastic_cache = None
        self._internal_steps = 0  # internal steps taken
        self._estimated_at = 0  # internal step count at the last periodic re-estimate (keys the elastic bound)
        self.step_count = 0
        self.time = 0.0
        # the last good state, restored when a step raises (blow-up, interrupt); _broken: the error every
        # further step repeats when even that state is not finite (corrupted behind the API's back)
        self._checkpoint = Checkpoint(self.state.xv)
        self._broken: SimulationError | None = None
        self._tangled_at = np.full(self.worlds, -1, dtype=np.int64)  # output step each world was found tangled
        self._tangle_checked_at = 0  # internal step of the last tangle check
        self._face_corners = tuple(np.ascontiguousarray(self.design.rest.faces[:, k]) for k in range(3))
        self._refine = 1  # automatic substeps x this after a blow-up within the estimate (see _retry)
        self._volume_cmds = [None, None]  # per state: the prepared volume launch of the chamber check
        self._vol_view = None  # on CPU: a NumPy view of _vol_probe (set with _volume_cmds)
        self._static = None  # the quasi-static settle's buffers (StaticSettle), made at its first use
        self._update_plan()

    # ------------------------------------------------------------------ world helpers
    def _out(self, a: np.ndarray):
        return a[0] if self.worlds == 1 else a

    def _per_world(self, value, shape_tail: tuple, name: str, stored=np.float64) -> np.ndarray:
        a = numeric_array(value, name)
        full = (self.worlds,) + shape_tail
        if a.shape == shape_tail:
            a = np.broadcast_to(a, full)
        if a.shape != full:
            raise DesignError(f"{name} must have shape {shape_tail} or {full}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise DesignError(f"{name} must be finite; got non-finite values")
        with np.errstate(over="ignore"):
            kept = a.astype(stored)
        if not np.all(np.isfinite(kept)):
            big = float(np.abs(a).max())
            raise DesignError(f"{name} up to {big:.3g} do not fit in {np.dtype(stored).name} (stored as "
                              f"{np.dtype(stored).name} at precision {self.precision!r}); use realistic values "
                              f"(SI units) or precision='float64'")
        return np.ascontiguousarray(a)

    def _direct(self, kernel, dim, inputs):
        wp.launch(kernel, dim, inputs, device=self.device)

    # ------------------------------------------------------------------ state access
    @property
    def state(self) -> State:
        """The current ``State`` (one of the two the steps alternate between)."""
        return self._states[self.plan.parity]

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) float64 positions in m ((W, V, 3) with several worlds)."""
        return self._out(self.state.x.numpy().astype(np.float64))

    @positions.setter
    def positions(self, value):
        a = self._per_world(value, (self.model.n_vertices, 3), "positions", self.model.np_dtype)
        check_chamber(a, self.model.host.faces, self.model.np_dtype, float(self.model.host.rest_length.min()))
        self.state.x.assign(a.astype(self.model.np_dtype))
        if self.solver.recenter(a):
            self.plan.invalidate()
        self._geometry_version += 1
        self._dirty = True
        self._recover()

    @property
    def velocities(self) -> np.ndarray:
        """(V, 3) float64 velocities in m/s ((W, V, 3) with several worlds)."""
        return self._out(self.state.v.numpy().astype(np.float64))

    @velocities.setter
    def velocities(self, value):
        a = self._per_world(value, (self.model.n_vertices, 3), "velocities", self.model.np_dtype)
        self.state.v.assign(a.astype(self.model.np_dtype))
        self._recover()

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
        if not np.array_equal(a, self.control.air.numpy()):  # the same air again changes no step
            self.control.air.assign(a)
            self._dirty = True

    def _ipam_pressure(self) -> np.ndarray:
        return self.control.ipam_pressure.numpy()[:, : self.model.n_ipams]

    @property
    def ipam_pressures(self) -> np.ndarray:
        """(n_ipam,) IPAM gauge pressures in Pa ((W, n_ipam) with several worlds)."""
        return self._out(self._ipam_pressure().copy())

    @ipam_pressures.setter
    def ipam_pressures(self, value):
        if self.model.n_ipams == 0:
            raise DesignError("this design has no IPAMs; add one with Design.add_ipam before setting pressures")
        self.set_actuator_controls("ipam", value, "ipam_pressures")

    def _family(self, family: str):
        fam = next((f for f in self.model.families if f.name == family), None)
        if fam is None:
            raise DesignError(f"this design has no actuators of family {family!r}; its families: "
                              f"{[f.name for f in self.model.families]}")
        if not fam.controlled:
            raise DesignError(f"force family {family!r} is passive: its {fam.plural} take no control and no mask")
        return fam

    def actuator_controls(self, family: str) -> np.ndarray:
        """(n,) the controls of actuator family ``family``'s elements ((W, n) with several worlds); the
        IPAM's are ``ipam_pressures``."""
        self._family(family)
        return self._out(self.control.values[family].numpy()[:, : self.model.host.count(family)].copy())

    def set_actuator_controls(self, family: str, value, name: str | None = None) -> None:
        """Set the controls of actuator family ``family``'s elements ((n,) or (W, n)), each within the
        family's limits; ``name`` names the value in errors."""
        fam, n = self._family(family), self.model.host.count(family)
        a = self._per_world(value, (n,), name or f"{family} controls")
        lim = fam.control_limits(self.model.host.actuators[family])
        if lim is not None:
            low, high = a < lim[:, 0] - 1e-9, a > lim[:, 1] + 1e-9
            if np.any(low | high):
                w, i = np.argwhere(low | high)[0]
                unit = fam.control_unit
                raise DesignError(
                    f"{fam.label} {i} {fam.control_name} {a[w, i]:.6g} {unit} is outside its limits "
                    f"[{lim[i, 0]:.6g}, {lim[i, 1]:.6g}] {unit}; clip it or widen {fam.limits_name} in {fam.owner}")
        if n:
            full = self.control.values[family].numpy().copy()
            full[:, :n] = a
            self.control.values[family].assign(full)

    def _mask(self, value, n: int, name: str) -> np.ndarray:
        a = np.asarray(value)
        if a.dtype != bool or a.shape not in ((n,), (self.worlds, n)):
            raise DesignError(f"{name} must be a bool array of shape ({n},) or ({self.worlds}, {n}), got "
                              f"{a.dtype} {a.shape}")
        return np.ascontiguousarray(np.broadcast_to(a, (self.worlds, n)))

    @property
    def ipam_mask(self) -> np.ndarray:
        """(n_ipam,) bool, False where an IPAM is masked out of the world ((W, n_ipam) with several
        worlds): it exerts no force there. One model can so hold alternative actuator sets."""
        return self.actuator_mask("ipam")

    @ipam_mask.setter
    def ipam_mask(self, value):
        self.set_actuator_mask("ipam", value, "ipam_mask")

    def actuator_mask(self, family: str) -> np.ndarray:
        """(n,) bool, False where an element of actuator family ``family`` is masked out of the world
        ((W, n) with several worlds); the IPAM's is ``ipam_mask``."""
        self._family(family)
        return self._out(self.control.enabled[family].numpy()[:, : self.model.host.count(family)].astype(bool))

    def set_actuator_mask(self, family: str, value, name: str | None = None) -> None:
        """Mask elements of actuator family ``family`` out of worlds (a bool (n,) or (W, n) array,
        False: no force there); ``name`` names the value in errors."""
        self._family(family)
        n = self.model.host.count(family)
        a = self._mask(value, n, name or f"{family} mask")
        full = np.ones((self.worlds, max(n, 1)), dtype=np.int32)
        full[:, :n] = a
        self.control.enabled[family].assign(full)

    @property
    def cell_mask(self) -> np.ndarray:
        """(n_cell,) bool, False where a cell is masked out of the world ((W, n_cell)): it never jams there."""
        return self._out(self.state.cell_enabled.copy())

    @cell_mask.setter
    def cell_mask(self, value):
        a = self._mask(value, self.model.n_cells, "cell_mask")
        if np.any(~a & self.state.cell_jammed):
            w, c = np.argwhere(~a & self.state.cell_jammed)[0]
            raise DesignError(f"cell {c} is already jammed in world {w}; mask cells out before they jam")
        self.state.cell_enabled[:] = a

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
        if world is not None and (isinstance(world, (bool, np.bool_)) or not isinstance(world, (int, np.integer))):
            raise DesignError(f"world must be None (every world) or an integer index, got {world!r}")
        worlds = range(self.worlds) if world is None else [int(world)]
        for w in worlds:
            if not 0 <= w < self.worlds:
                raise DesignError(f"world must be in 0..{self.worlds - 1}, got {w}")
            if not self.state.cell_jammed[w, cell] and self.state.cell_enabled[w, cell]:  # masked: never jams
                mask[w] = 1
        if not mask.any():
            return
        edge, jammed = wp.clone(self.state.edge), wp.clone(self.state.jammed)  # undone whole if interrupted
        family_jam = {k: {n: wp.clone(a) for n, a in f.items()} for k, f in self.state.family_jam.items()}
        try:
            eval_jam(m, self.state, cell, wp.array(mask, dtype=wp.int32, device=self.device), self._direct)
            self.state.cell_jammed[mask.astype(bool), cell] = True
            self.state.cell_jam_time[mask.astype(bool), cell] = self.time
        except BaseException:
            wp.copy(self.state.edge, edge)
            wp.copy(self.state.jammed, jammed)
            for k, f in family_jam.items():
                for n, a in f.items():
                    wp.copy(self.state.family_jam[k][n], a)
            self.state.cell_jammed[mask.astype(bool), cell] = False
            self.state.cell_jam_time[mask.astype(bool), cell] = np.nan
            raise
        self._dirty = True

    # ------------------------------------------------------------------ worlds between simulators
    def snapshot(self) -> list[WorldRef]:
        """Every world's state now (positions, velocities, jam fields, air, IPAM pressures), copied on
        the device: one ``WorldRef`` per world, for ``load_worlds`` of this or another simulator of
        the same design and precision."""
        state, control = self.state.clone(), self.control.clone()
        return [WorldRef(state, control, w) for w in range(self.worlds)]

    def load_worlds(self, worlds: list[WorldRef]) -> None:
        """Load one world per world of this simulator (``len(worlds) == self.worlds``), copied on the
        device from their snapshots (``snapshot``); time is left as it is. The IPAM and cell masks stay
        this simulator's."""
        if len(worlds) != self.worlds:
            raise DesignError(f"load_worlds needs one world per world ({self.worlds}), got {len(worlds)}")
        groups: dict[int, list] = {}
        for dst, ref in enumerate(worlds):
            groups.setdefault(id(ref.state), []).append((ref, dst))
        for group in groups.values():  # all checked before any is copied
            check_layout(group[0][0].state, group[0][0].control, self.state, self.control)
        for group in groups.values():
            ref = group[0][0]
            copy_worlds(ref.state, ref.control, [r.world for r, _ in group], self.state, self.control,
                        [d for _, d in group], self.device)
        if self.solver.recenter(self.state.x.numpy()):  # as for positions set: the blow-up region follows
            self.plan.invalidate()
        self._geometry_version += 1
        self._dirty = True
        self._recover()

    # ------------------------------------------------------------------ read-outs
    def forces(self, term: str | None = None) -> np.ndarray:
        """Total force on every vertex (N), all terms and damping included; or one term of
        ``FORCE_TERMS`` ('spring' (with its dampers), 'bending', 'pressure', 'ipam', 'viscous') or
        of the model's other actuator families (by family name)."""
        terms = force_terms(self.model)
        if term is not None and term not in terms:
            raise DesignError(f"unknown force term {term!r}; choose one of {terms}")
        st, paper = self.state, self.bending == "paper"
        if term is None:  # the total goes through the same fused kernels as a step
            eval_forces_fused(self.model, st, self.control, self._fg_probe, self._vol2_probe, self._direct,
                              paper_bending=paper)
        else:
            eval_forces(self.model, st, self.control, st.x, st.v, self._fg_probe[0], self._vol_probe, self._direct,
                        paper_bending=paper, terms=(term,))
        return self._out(self._fg_probe[0].numpy().astype(np.float64))

    def _volumes(self) -> np.ndarray:
        """(W,) chamber volumes, m^3, through one prepared launch per state (``step`` reads them after
        every output step on CPU): a captured graph where the plan captures its steps, else the
        recorded launch. On CPU the probe is zeroed and read through a NumPy view of its memory."""
        if self._volume_cmds[0] is None:  # one per state, both prepared at the first use
            self._prepare_volumes()
        view = self._vol_view
        if view is None:
            self._vol_probe.zero_()
        else:
            view.fill(0.0)
        self._volume_cmds[self.plan.parity]()
        return self._vol_probe.numpy().copy() if view is None else view.copy()

    def _prepare_volumes(self) -> None:
        for p, state in enumerate(self._states):
            cmds = []
            eval_volume(self.model, state.x, self._vol_probe,
                        lambda k, dim, inputs: cmds.append(wp.launch(k, dim, inputs, device=self.device,
                                                                     record_cmd=True)))
            self._volume_cmds[p] = cmds[0].launch
        cpu = wp.get_device(self.device).is_cpu
        self._vol_view = self._vol_probe.numpy() if cpu else None  # host memory: a view, no copy
        if cpu and self.plan.mode == "graph":  # a graph replay packs no launch arguments in Python
            try:
                graphs = []
                for launch in self._volume_cmds:
                    with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                        launch()
                    graphs.append(capture.graph)
            except Exception:  # capture unsupported here: the recorded launches stay
                return
            self._volume_cmds = [partial(wp.capture_launch, g) for g in graphs]

    def volume(self):
        """Enclosed volume in m^3 (float; (W,) with several worlds)."""
        v = self._volumes()
        return float(v[0]) if self.worlds == 1 else v

    def pressure(self):
        """Chamber gauge pressure n R T / V - p_atm in Pa."""
        m = self.model
        p = gauge_pressure_np(self.control.air.numpy(), self._volumes(), m.gas_rt, m.atmospheric_pressure)
        return float(p[0]) if self.worlds == 1 else p

    def ipam_lengths(self) -> np.ndarray:
        """(n_ipam,) distance between the centroids of each IPAM's end faces (m)."""
        h = self.model.host
        if self.model.n_ipams == 0:
            return self._out(np.zeros((self.worlds, 0)))
        return self._out(ipam_lengths_np(self.state.x.numpy().astype(np.float64), h.faces, h.ipam_faces))

    def ipam_forces(self) -> np.ndarray:
        """(n_ipam,) axial force k (L - L_n) in N, positive = tension."""
        h = self.model.host
        if self.model.n_ipams == 0:
            return self._out(np.zeros((self.worlds, 0)))
        length = ipam_lengths_np(self.state.x.numpy().astype(np.float64), h.faces, h.ipam_faces)
        natural = natural_length_np(h.ipam_free_length, h.ipam_area_over_k, self._ipam_pressure())
        return self._out(axial_force_np(h.ipam_stiffness, length, natural) * self.ipam_mask.reshape(self.worlds, -1))

    def edge_state(self):
        """Current (lengths, dihedral angles) of every edge, each (E,) (or (W, E))."""
        self._direct(kc.edge_state_kernel, (self.worlds, self.model.n_edges),
                     [self.model.hinges, self.state.x, self._edge_len, self._edge_ang])
        return self._out(self._edge_len.numpy().astype(np.float64)), self._out(self._edge_ang.numpy().astype(np.float64))

    def energy(self) -> dict:
        """Mechanical energy terms in J (float64, host): kinetic, spring, bending, gas, one per actuator
        family of the model (ipam, ...), total.

        Gas energy is p_atm V - n R T ln V (its negative gradient is the pressure force); the
        total is conserved by the undamped dynamics with fixed air and IPAM pressures.
        """
        m, h, st = self.model, self.model.host, self.state
        x = st.x.numpy().astype(np.float64)
        v = st.v.numpy().astype(np.float64)
        jam = st.jammed.numpy().astype(bool)
        zero = np.zeros(self.worlds)
        k = h.edge_stiffness * jammed_factor_np(jam, m.jam_stretch_factor)
        out = dict(kinetic=0.5 * np.einsum("v,wvi,wvi->w", h.mass, v, v),
                   spring=spring_energy_np(x, h.hinges, st.rest_length.numpy(), k), bending=zero,
                   gas=gas_energy_np(volumes_np(x, h.faces), self.control.air.numpy(), m.gas_rt,
                                     m.atmospheric_pressure))
        for fam in m.families:
            n = m.host.count(fam.name)
            fields = {"jam": {name: a.numpy() for name, a in st.family_jam[fam.name].items()}} \
                if fam.name in st.family_jam else {}
            out[fam.name] = fam.energy(h.actuators[fam.name], x, self.control.values[fam.name].numpy()[:, :n],
                                       self.control.enabled[fam.name].numpy()[:, :n].astype(bool), **fields)
        if m.has_bending:
            kt = h.bend_stiffness * jammed_factor_np(jam, m.jam_bend_factor)
            out["bending"] = bending_energy_np(x, h.hinges, st.rest_angle.numpy(), kt)
        out["total"] = sum(out.values())
        return {key: (float(val[0]) if self.worlds == 1 else val) for key, val in out.items()}

    # ------------------------------------------------------------------ stepping
    def stable_dt(self) -> float:
        """Current conservative stable internal step (s), the minimum over worlds (estimated once
        when every world holds the same state).

        The elastic part of the bound (a short Lanczos run, see stability.elastic_omega2_bound) and
        the Gershgorin rows that depend on the jam state alone (``stability.jam_rows``) are cached per
        world until a cell of that world jams (only the worlds that jammed are estimated again),
        positions are set or ``reestimate_every`` internal steps pass; air changes only re-evaluate
        the pressure and gas terms (one kernel launch, ``physics.pressure.pressure_rows``)."""
        m, st = self.model, self.state
        edge_jam, x, rest = st.jammed.numpy(), st.x.numpy(), st.rest_length.numpy()
        air = self.control.air.numpy()
        uniform = worlds_identical(edge_jam, x, rest, air)
        if uniform:  # identical worlds (a batch as built, before its worlds part): estimate one
            edge_jam, x, rest, air = edge_jam[:1], x[:1], rest[:1], air[:1]
        edge_jam, x, rest = edge_jam.astype(bool), x.astype(np.float64), rest.astype(np.float64)
        key = (self._geometry_version, self._estimated_at, uniform)
        jams = edge_jam.sum(axis=1)  # (W,) a world's jam state only grows between position sets
        with np.errstate(all="ignore"):
            try:
                cache = self._elastic_cache
                if cache is None or cache[0] != key:
                    cache = (key, jams, elastic_omega2_bound(m, edge_jam, x, rest), jam_rows(m, edge_jam))
                elif np.any(jams != cache[1]):  # only the worlds that jammed since: the others keep theirs
                    changed = np.flatnonzero(jams != cache[1])
                    bound, stiff, damp = cache[2].copy(), cache[3][0].copy(), cache[3][1].copy()
                    bound[changed] = elastic_omega2_bound(m, edge_jam[changed], x[changed], rest[changed])
                    stiff[changed], damp[changed] = jam_rows(m, edge_jam[changed])
                    cache = (key, jams, bound, (stiff, damp))
                self._elastic_cache = cache
                est = stable_dt_estimate(m, type(self.solver), edge_jam, air, x, rest, elastic_bound=cache[2],
                                         rows=cache[3], pressure=pressure_rows(m, st.x, air, len(air)))
            except np.linalg.LinAlgError:  # a non-finite or degenerate state: no estimate
                est = np.array([np.nan])
        return check_stable_dt(float(est.min()), self.step_count, self.time)

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

    @property
    def step_kernels(self) -> list[str]:
        """Kernel names launched by one internal step."""
        return self.plan.kernel_names

    def _update_plan(self):
        self._dt_stable = self.stable_dt()
        fixed = self.settings.substeps
        n = substeps_for(self.dt, self._dt_stable) * self._refine if fixed is None else fixed
        h = self.dt / n
        if fixed is not None:
            check_fixed_step(self.dt, n, self._dt_stable, self.integrator)
        if n > self.settings.max_substeps:
            st = self.state
            raise substeps_error(self.design, self.model, st.jammed.numpy().astype(bool), self.control.air.numpy(),
                                 st.x.numpy().astype(np.float64), self.dt, self._dt_stable, self.settings.max_substeps)
        self._substeps = n
        if h != self.plan.h or not self.plan.built:
            self.plan.build(self.solver, h, self._states, self.control)
        self._dirty = False

    def _report(self, found):
        # found: None or (output step, (W,) codes) from the blow-up watch
        if found is not None:
            step, codes = found
            time = self.time - (self.step_count - step) * self.dt
            raise blowup_error(codes, step, time, self.plan.h, self._dt_stable)

    def check_volume(self) -> None:
        """Raise ``SimulationError`` when a world's chamber volume is not positive (membrane turned
        inside out or collapsed). ``step`` calls it after each output step where the host reads the
        state anyway (CPU): such a step is a blow-up of that step."""
        vol = self._volumes()
        if (vol > 0).all():
            return
        w = int(np.argmin(vol))
        safe = 0.5 * min(self._dt_stable, self.plan.h)
        raise SimulationError(
            f"simulation blew up at output step {self.step_count} (t = {self.time:.6g} s, world {w}): the chamber "
            f"volume became {vol[w]:.3g} m^3 (membrane inside out or collapsed) with internal step "
            f"{self.plan.h:.4g} s; stable estimate {self._dt_stable:.4g} s. Try a smaller step, e.g. dt = "
            f"{safe:.3g} s with substeps=1, or check the inputs (air, pressures, stiffness) for extreme values",
            step=self.step_count, quantity="volume", safe_dt=safe, world=w)

    def check_tangle(self) -> None:
        """Raise ``SimulationError`` when a world's membrane has passed through itself at two checks in a
        row (tangled by a violent motion: folded faces and winding numbers above 1, which the volume check
        can miss; the model has no self-contact, and a crumple that untangles within ``TANGLE_EVERY``
        output steps, like a 100-atmosphere recoil, is let through). Cheap first: only a world with more
        than ``INWARD_FACES`` of its faces facing its centre is tested exactly (``crossing.self_crossing``).
        ``step`` calls it every ``TANGLE_EVERY`` output steps, at least ``TANGLE_MIN_INTERNAL`` internal
        steps apart, where it checks the volume."""
        rest = self.design.rest
        x = self.state.x.numpy().reshape(self.worlds, -1, 3)
        suspect = np.flatnonzero(inward_fraction(x, self._face_corners) > INWARD_FACES)
        x = x[suspect].astype(np.float64)
        hits = self_crossing(x, rest, device="cpu") if suspect.size else []
        found = {int(suspect[w]): (e, face, n) for w, e, face, n in hits}
        before = self._tangled_at.copy()
        self._tangled_at[:] = -1
        for w in found:
            self._tangled_at[w] = before[w] if before[w] >= 0 else self.step_count
        persistent = [w for w in found if before[w] >= 0]
        if not persistent:
            return
        w = persistent[0]
        (e, face, n), since = found[w], int(before[w])
        a, b = rest.edges[e]
        safe = 0.5 * min(self._dt_stable, self.plan.h)
        raise SimulationError(
            f"simulation tangled at output step {self.step_count} (t = {self.time:.6g} s, world {w}): the membrane "
            f"passes through itself since output step {since} ({n} edges cross a face, e.g. edge ({a}, {b}) through "
            f"face {face}) with internal "
            f"step {self.plan.h:.4g} s. Try a smaller step, e.g. dt = {safe:.3g} s with substeps=1, or check the "
            f"state set and the inputs (air, pressures, stiffness) for extreme values",
            step=self.step_count, quantity="tangle", safe_dt=safe, world=w)

    # ------------------------------------------------------------------ last good state
    _KEPT = ("step_count", "time", "_internal_steps", "_estimated_at", "_tangle_checked_at")

    def _save(self) -> None:
        self._checkpoint.save(self.state.xv, {"parity": self.plan.parity, **{k: getattr(self, k) for k in self._KEPT}})

    def _finite(self) -> bool:
        return bool(np.all(np.isfinite(self.state.xv.numpy())))

    def _restore(self, exc: BaseException) -> None:
        """Back to the last good state after ``exc`` interrupted a step; a state that is not finite
        even there (changed behind the API's back) leaves the simulator refusing further steps."""
        self.plan.parity = self._checkpoint.host["parity"]  # the state the checkpoint was taken of
        for k, v in self._checkpoint.restore(self.state.xv).items():
            if k != "parity":
                setattr(self, k, v)
        self.blowup_watch.reset()
        self._dirty = True  # the stable step is estimated anew for the restored state
        if isinstance(exc, SimulationError) and not self._finite():
            self._broken = exc

    def _recover(self) -> None:
        """A state set through the API: shorter steps taken after a blow-up end, and a finite state
        lifts the refusal."""
        self._checkpoint.current = False
        self._tangled_at[:] = -1
        if self._refine != 1:
            self._refine, self._dirty = 1, True
        if self._broken is not None and self._finite():
            self._broken = None

    def step(self, n: int = 1) -> None:
        """Advance n output steps of dt (each ``substeps`` internal steps), checking for blow-up.

        The blow-up error names the first output step after which a world blew up. Any error or
        interrupt (Ctrl-C) inside a step leaves the last good state: on CPU the state after the last
        whole output step, on a GPU (where blow-up codes are read at the end of the call and before
        each re-estimate of the stable step) the state at the start of the call; positions,
        velocities, ``step_count`` and ``time`` always agree."""
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
            raise DesignError(f"step count must be an integer >= 0, got {n!r}")
        if self._broken is not None:
            b = self._broken
            raise SimulationError(f"{b} (the state is not finite; set positions and velocities to continue)",
                                  step=b.step, quantity=b.quantity, safe_dt=b.safe_dt, world=b.world)
        target = self.step_count + int(n)
        first, refine = None, self._refine
        while True:
            if not self._checkpoint.current:  # else the save after the last output step still holds
                self._save()
            try:
                self._advance(target - self.step_count)
                return
            except BaseException as exc:
                self._restore(exc)
                first = first or exc
                if not self._retry(exc):
                    if first is exc or not isinstance(first, SimulationError):
                        raise
                    raise SimulationError(  # the first failure names the cause; say the retries failed too
                        f"{first} (also with {self._refine // refine}x shorter internal steps)", step=first.step,
                        quantity=first.quantity, safe_dt=first.safe_dt, world=first.world) from exc

    def _retry(self, exc: BaseException) -> bool:
        """Whether to take the failed output steps again with internal steps half as long.

        The stable-step estimate holds for the state it was made at; a violent motion between two
        estimates (a membrane at 100 atm sloshing at hundreds of m/s, crumpling as it recoils) can
        need a smaller step before the next one. With automatic substeps a blow-up from a finite last
        good state is retried at 2x, 4x, 8x the substeps (``MAX_REFINE``, within ``max_substeps``);
        the refinement halves again at each periodic re-estimate. Only then is the blow-up raised."""
        if not isinstance(exc, SimulationError) or exc.quantity == "estimate" or self._broken is not None \
                or self.settings.substeps is not None or self._refine >= MAX_REFINE \
                or 2 * (self._substeps or 1) > self.settings.max_substeps:
            return False
        self._refine *= 2
        self._dirty = True
        return True

    def _advance(self, n: int) -> None:
        watch = self.blowup_watch
        for _ in range(n):
            if self.reestimate_every and self._internal_steps - self._estimated_at >= self.reestimate_every:
                self._estimated_at = self._internal_steps
                self._refine = max(1, self._refine // 2)
                self._dirty = True
            if self._dirty:
                self._report(watch.poll())  # the estimate reads the state: a blown-up one is reported first
                self._update_plan()
            self._checkpoint.current = False
            self.plan.run(self._substeps)
            self._internal_steps += self._substeps
            self.step_count += 1
            self.time += self.dt
            self._report(watch.after_step(self.step_count))
            if not watch.deferred:  # each whole output step with a chamber left is the new last good state
                self.check_volume()
                if self.step_count % TANGLE_EVERY == 0 and \
                        self._internal_steps - self._tangle_checked_at >= TANGLE_MIN_INTERNAL:
                    self._tangle_checked_at = self._internal_steps
                    self.check_tangle()
                self._save()
        self._report(watch.poll())

    def settle_static(self, tolerance: float | None = None, max_iterations: int = MAX_ITERATIONS) -> Equilibrium:
        """Move every world to the equilibrium of its current controls and jam state (the minimum of the
        potential energy reached from the current positions, ``equilibrium.StaticSettle``), velocities
        zero; simulated time does not advance. ``tolerance``: the largest residual vertex force (N) of a
        converged world (None: ``equilibrium.FORCE_TOLERANCE`` of the precision). Returns what it did (``Equilibrium``: per world status, force evaluations and
        residual). A world that stalls, starts from an invalid state or settles passing through itself
        raises ``SimulationError`` naming it (the state is then left as it was); one not converged within ``max_iterations`` is
        left at its best point (``Equilibrium.converged`` False). Needs ``bending="exact"``: the paper's
        eq. (9) forces are no energy's gradient."""
        if self.bending != "exact":
            raise DesignError("a static settle needs bending='exact': the paper variant's forces (eq. 9) are not "
                              "the gradient of an energy, so they have no equilibrium to find; use settle='dynamic'")
        if self._broken is not None:
            self.step(0)  # raises the error that left the state broken
        if self._static is None:
            self._static = StaticSettle(self.model, self.worlds, self.solver.x_bound, self.solver.size)
        self._static.x_bound = self.solver.x_bound  # the blow-up region follows positions set far away
        if not self._checkpoint.current:
            self._save()
        out = self._static.solve(self.state, self.control, tolerance, max_iterations)
        bad = np.flatnonzero((out.status == 2) | (out.status == 3))
        tangled = self._static_tangles() if not bad.size else []
        if tangled:
            self._restore(SimulationError("static settle"))
            w, e, face, n = tangled[0]
            a, b = self.design.rest.edges[e]
            raise SimulationError(
                f"static settle failed in world {w}: its equilibrium passes through itself ({n} edges cross a face, e.g. "
                f"edge ({a}, {b}) through face {face}); the model has no self-contact, so check the controls for "
                f"extreme values", quantity="tangle", world=int(w))
        if bad.size:
            self._restore(SimulationError("static settle"))
            w = int(bad[0])
            raise SimulationError(
                f"static settle failed in world {w}: {STATUS_NAMES[int(out.status[w])]} after {int(out.evaluations[w])} "
                f"force evaluations (largest residual force {out.residual[w]:.3g} N); check the controls and the state "
                f"for extreme values, or settle by the dynamics (settle='dynamic', Simulator.step)",
                quantity="equilibrium", world=w)
        self._geometry_version += 1
        self._dirty = True
        self._recover()
        return out

    def _static_tangles(self) -> list:
        """The worlds whose settled membrane passes through itself (``crossing.self_crossing`` rows), tested
        exactly only where more than ``INWARD_FACES`` of the faces face the centre. An equilibrium does
        not untangle later, so one such check is decisive (the dynamics' ``check_tangle`` waits for two)."""
        x = self.state.x.numpy().reshape(self.worlds, -1, 3)
        suspect = np.flatnonzero(inward_fraction(x, self._face_corners) > INWARD_FACES)
        if not suspect.size:
            return []
        hits = self_crossing(x[suspect].astype(np.float64), self.design.rest, device="cpu")
        return [(int(suspect[w]), e, face, n) for w, e, face, n in hits]

    def __repr__(self) -> str:
        return (f"Simulator({self.design!r}, device={self.device!r}, integrator={self.integrator!r}, dt={self.dt}, "
                f"precision={self.precision!r}, worlds={self.worlds})")
