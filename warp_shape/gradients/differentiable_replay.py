"""The differentiable replay: a control result's sequence replayed open loop, and its adjoint.

The forward replay is ``controller.open_loop``'s, on the simulator's own fused step; it fixes the
schedule (the internal step of every output step, the jam events) and keeps checkpoints every
``segment`` internal steps at most. The adjoint runs backwards over segments: each is recomputed from
its checkpoint with the backward-enabled kernels (``kernels/adjoint.py``), every internal step's
intermediates kept on a tape, then every internal step's adjoint is taken in reverse,
through the jam events (the frozen rest lengths and angles depend on the state they froze at) down to
the model's parameters and the rest shape. On a CPU with two cores the next segment is recomputed on a
second thread while the adjoint steps back through this one (``backward(threads=)``).
docs/gradients.md gives the algorithm and its cost.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import warp as wp

from warp_shape.kernels import adjoint as ka

from ..controller.open_loop import control_schedule, family_schedule
from ..controller.shard import available_cores, in_worker
from ..controller.worlds import mask_passive, passive_masks
from ..display import Design
from ..errors import DesignError
from ..model import PRECISIONS, host_model
from ..simulator import Simulator
from ..step_plan import create_overloads
from .families import ReplayFamilies, controls_gradient_name
from .step_adjoints import adjoint_launch

__all__ = ["ReplayPlan", "DifferentiableReplay", "ReplayGradient"]


@dataclass
class ReplayPlan:
    """What the forward replay fixed (N output steps, R history rows, J jam events).

    ``h`` (N,) internal step of each output step (s) and ``substeps`` (N,) their count; ``row`` (N,)
    the history row whose controls hold during each output step; ``air`` (R,) mol and ``pressures``
    (R, n_ipam) Pa the rows' controls; ``jam_steps`` (J,) the output steps before which cells jam and
    ``jam_edges`` J x (edges newly jammed there); ``checkpoints`` {output step: (2, V, 3) float64
    state}, ``edges`` J + 1 x (4, E) the edge fields of each jam phase; ``final`` (V, 3) positions at
    the end; ``segment`` the internal steps between checkpoints at most; ``precision`` the replay's."""

    h: np.ndarray
    substeps: np.ndarray
    row: np.ndarray
    air: np.ndarray
    pressures: np.ndarray
    enabled: np.ndarray
    jam_steps: list
    jam_edges: list
    checkpoints: dict
    edges: list
    jam_states: list
    final: np.ndarray
    segment: int
    precision: str = "float64"
    family_controls: dict = field(default_factory=dict)  # {family: (R, n)} the other actuator families' controls
    # J + 1 x {family: {field: array}}: the jam fields (world 0) of each jam phase of every family that jams
    family_jams: list = field(default_factory=list)
    family_jam_now: list = field(default_factory=list)  # J x {family: (n,) int32}: its elements jammed at each event

    @property
    def n_steps(self) -> int:
        return len(self.h)

    @property
    def internal_steps(self) -> int:
        return int(self.substeps.sum())


#: internal steps between two checkpoints at most: the adjoint keeps one segment's intermediates on
#: the tape (per internal step with RK4: 16 V vectors, 4 volumes and 4 E angles; their adjoints only for
#: the step in hand), so this bounds its memory (measured peak: 13 MB at 642 vertices, 56 MB at 2562 in
#: float64, ``bench gradient``)
MAX_SEGMENT = 32


def segment_budget(internal_steps: int) -> int:
    """Internal steps between checkpoints: the square root of the replay's count, at most ``MAX_SEGMENT``."""
    return max(1, min(MAX_SEGMENT, int(math.ceil(math.sqrt(max(internal_steps, 1))))))


def plan_replay(design: Design, result, *, precision: str = "float64", device: str = "cpu",
                segment: int | None = None) -> ReplayPlan:
    """Replay ``result``'s sequence on ``design`` with the simulator (as ``ws.replay``) and record
    the plan the adjoint needs (see ``ReplayPlan``); ``segment``: internal steps between checkpoints
    at most (an output step's substeps are never split; None: ``segment_budget``)."""
    settings = result.settings.simulation.replace(precision=precision)
    sim = Simulator(design, device=device, settings=settings, worlds=1)
    steps, air, pressures, jam = control_schedule(result, sim.dt)
    fam_controls = family_schedule(result, sim.model)
    pi, pc = passive_masks([result], design.n_ipams, design.n_cells)
    mask_passive(sim, pi, pc)
    n = int(steps[-1])
    seg = segment_budget(n * sim.substeps) if segment is None else max(1, int(segment))
    since, last = 0, sim.substeps  # internal steps since the last checkpoint; the last output step's
    h, sub, row = np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    checkpoints, jam_steps, jam_edges, jam_states = {}, [], [], []
    edges = [sim.state.edge.numpy()[:, 0].astype(np.float64)]
    family_jams, family_jam_now = [_family_jam_of(sim)], []
    marks = np.unique(steps)
    for a, b in zip(marks[:-1], marks[1:]):
        k = min(int(np.searchsorted(steps, b)), len(steps) - 1)
        new = [int(j) for j in np.flatnonzero(jam[k] & ~np.asarray(sim.jammed).reshape(-1) & ~pc[0])]
        if new:
            before = sim.state.jammed.numpy()[0].astype(bool)
            jam_states.append(_state_of(sim))
            for j in new:
                sim.jam(j)
            jam_steps.append(int(a))
            jam_edges.append(np.flatnonzero(sim.state.jammed.numpy()[0].astype(bool) & ~before))
            edges.append(sim.state.edge.numpy()[:, 0].astype(np.float64))
            family_jams.append(_family_jam_of(sim))
            family_jam_now.append({name: (fields[_jam_flags(sim, name)] & ~family_jams[-2][name][_jam_flags(sim, name)]
                                          ).reshape(-1).astype(np.int32) for name, fields in family_jams[-1].items()})
        sim.air_moles = float(air[k])
        if design.n_ipams:
            sim.ipam_pressures = pressures[k]
        for name, rows in fam_controls.items():
            sim.set_actuator_controls(name, rows[k])
        for s in range(int(a), int(b)):
            if s == 0 or since + last > seg:
                checkpoints[s], since = _state_of(sim), 0
            sim.step(1)
            h[s], sub[s], row[s] = sim.internal_dt, sim.substeps, k
            since, last = since + int(sub[s]), int(sub[s])
    return ReplayPlan(h=h, substeps=sub, row=row, air=air, pressures=pressures,
                      enabled=(~pi[0]).astype(np.int32), jam_steps=jam_steps, jam_edges=jam_edges,
                      checkpoints=checkpoints, edges=edges, jam_states=jam_states,
                      final=np.asarray(sim.positions, dtype=np.float64).reshape(-1, 3), segment=seg,
                      precision=precision, family_controls=fam_controls, family_jams=family_jams,
                      family_jam_now=family_jam_now)


def _family_jam_of(sim) -> dict:
    """{family: {field: array}} world 0's jam fields of every family that jams (world axis kept, of size 1)."""
    return {name: {k: a.numpy()[..., 0:1, :].copy() for k, a in fields.items()}
            for name, fields in sim.state.family_jam.items()}


def _jam_flags(sim, name: str) -> str:
    return next(f.jam_flags for f in sim.model.families if f.name == name)


def _state_of(sim) -> np.ndarray:
    return np.stack([np.asarray(sim.positions, dtype=np.float64).reshape(-1, 3),
                     np.asarray(sim.velocities, dtype=np.float64).reshape(-1, 3)])


@dataclass
class StepBuffers:
    """One internal step's arrays: the state in and out (2, 1, V) and the intermediates (per stage the
    forces without pressure and dV/dx, the volume; the RK4 stage points and accelerations). ``rows``
    (R, 1, V) and ``volumes`` (S, 1, 1), where given, hold xv_in, fg, points and accel (in this order)
    and the volumes as views: the tape keeps the first ``kept`` rows (accel, which no adjoint reads,
    is left out)."""

    xv_in: wp.array
    xv_out: wp.array
    fg: list
    volume: list
    points: list
    accel: list
    rows: wp.array | None = None
    volumes: wp.array | None = None
    kept: int = 0


@dataclass
class Tape:
    """The intermediates of up to ``slots`` internal steps (see ``StepBuffers``): ``rows`` (slots, kept,
    V), ``volumes`` (slots, stages), the hinges' angles ``angles`` (slots, stages, E) and the slot in
    hand ``slot`` (1,) on the device, so that one captured graph serves every slot."""

    rows: wp.array
    volumes: wp.array
    angles: wp.array
    slot: wp.array

    @property
    def slots(self) -> int:
        return self.rows.shape[0]


@dataclass
class Lane:
    """What an internal step reads besides the model arrays: the edge fields ``edge`` (4, 1, E), the
    air ``air`` (1,) mol, the actuator families' controls and masks ``controls`` (values / enabled
    {family: (1, n)}: the IPAM's gauge pressures in Pa), the internal step ``step_h`` (1,) s, with the ``work`` buffers it runs on; ``loaded`` the (jam phase,
    history row, h) now in them. The adjoint runs on lane 0; a pipelined backward recomputes the next
    segment on lane 1 meanwhile, on a second thread."""

    edge: wp.array
    air: wp.array
    step_h: wp.array
    work: StepBuffers
    controls: SimpleNamespace  # the actuator families' controls: values / enabled {family: (1, n)}
    jam: dict = field(default_factory=dict)  # {family: {field: array}}: the jam fields in force (one world)
    loaded: list = field(default_factory=lambda: [None, None, None])

    @property
    def state(self) -> SimpleNamespace:
        """What the families' forces read of a state: the jam fields in force."""
        return ReplayFamilies.jam_state(self.jam)


@dataclass
class ReplayGradient:
    """d(loss)/d(parameter) of a replay, SI: ``rest_positions`` (V, 3) per m, ``youngs_modulus``
    per Pa and ``stretch_modulus`` per (N/m), ``bending_stiffness`` per (N m/rad), ``ipam_stiffness``
    (n,) per (N/m), ``ipam_area`` (n,) per m^2, ``air`` (R,) per mol and ``ipam_pressures`` (R, n) per
    Pa (one per history row: the controls in force up to that row; row 0's hold no step)."""

    loss: float
    values: dict


class DifferentiableReplay:
    """The replay of ``result`` on ``design`` and its adjoint, in ``precision`` on ``device``.

    ``forward()`` replays (``plan``); ``backward(dloss_dx)`` takes d(loss)/d(final positions) (V, 3)
    and returns every parameter's gradient (``ReplayGradient.values``). ``positions(params)``
    replays with changed parameters on the same schedule (for finite-difference checks)."""

    def __init__(self, design: Design, result, *, precision: str = "float64", device: str = "cpu",
                 segment: int | None = None):
        if not isinstance(design, Design):
            raise DesignError(f"a differentiable replay needs a ws.Design, got {type(design).__name__}")
        if precision not in PRECISIONS:
            raise DesignError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        self.design, self.result, self.precision, self.device = design, result, precision, str(device)
        self.segment = segment
        self.scalar, self.vec3, self.np_dtype = PRECISIONS[precision]
        self.host = host_model(design)
        self.integrator = result.settings.simulation.integrator
        self.paper_bending = int(result.settings.simulation.bending == "paper")
        self.plan: ReplayPlan | None = None
        self._graphs: dict = {}
        self._build_arrays()
        create_overloads(self.kernel_launches())

    # ------------------------------------------------------------------ arrays
    def _arr(self, a, dtype=None, grad=True):
        dtype = dtype or self.scalar
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device=self.device, requires_grad=grad)

    def _build_arrays(self) -> None:
        d, h = self.design, self.host
        V, E = len(h.rest_vertices), len(h.hinges)
        mat = d.material
        vec = lambda shape: wp.zeros(shape, dtype=self.vec3, device=self.device, requires_grad=True)  # noqa: E731
        sc = lambda shape: wp.zeros(shape, dtype=self.scalar, device=self.device, requires_grad=True)  # noqa: E731
        self.hinges = wp.array(h.hinges.astype(np.int32), dtype=wp.vec4i, device=self.device)
        self.owns = wp.array(h.hinge_owns, dtype=wp.int32, device=self.device)
        self.faces = wp.array(h.faces.astype(np.int32), dtype=wp.vec3i, device=self.device)
        # parameters
        self.rest = self._arr(h.rest_vertices.astype(self.np_dtype), self.vec3)
        self.stretch_modulus = self._arr(np.array([mat.stretch_modulus]))
        self.bending_stiffness = self._arr(np.array([mat.bending_stiffness]))
        face_scale = d.stretch_scale if d.stretch_scale is not None else np.ones(len(h.faces))
        self.wing_scale = self._arr(face_scale[h.hinge_faces].astype(self.np_dtype), grad=False)  # (E, 2)
        # derived model arrays (outputs of the build, inputs of every step)
        self.edge0 = sc((4, 1, E))
        self.mass, self.inv_mass = sc(V), sc(V)
        self.xv0 = vec((2, 1, V))
        self.fam = ReplayFamilies(self.host, self.faces, self.scalar, self.vec3, self.np_dtype, self.device,
                                  self.precision)
        self._vec, self._stages = vec, 4 if self.integrator == "rk4" else 1
        # the controls and edge fields in force with the work buffers, whose intermediates every
        # recomputed internal step leaves on a tape: lane 0 (the adjoint's; a pipelined backward
        # recomputes on lane 1, made when first needed); one step's buffers for the forward on the
        # kernels alone
        self.lanes = [self._lane()]
        self.single = self._buffers(vec((2, 1, V)), vec((2, 1, V)))
        self.tapes: list = [None, None]
        self._tape(1)
        # jam event buffers
        self.jam_now = wp.zeros(E, dtype=wp.int32, device=self.device)
        self.edge_before, self.edge_after = sc((4, 1, E)), sc((4, 1, E))
        self.xv_jam = vec((2, 1, V))
        self.fam_before, self.fam_after = self.fam.jam_fields(), self.fam.jam_fields()
        self.fam_now = {f.name: wp.zeros(self.host.count(f.name), dtype=wp.int32, device=self.device)
                        for f in self.fam.jamming}
        # a hyperelastic membrane's plate stiffness, which its family derives (the hinges' k_t follows it)
        membrane = self.fam.model.actuators.get("membrane", {})
        self.plate = membrane.get("plate", self._arr(np.zeros(1), grad=False))

    def _buffers(self, xv_in: wp.array, xv_out: wp.array) -> StepBuffers:
        V, vec, stages = len(self.host.rest_vertices), self._vec, self._stages
        return StepBuffers(xv_in=xv_in, xv_out=xv_out, fg=[vec((2, 1, V)) for _ in range(stages)],
                           volume=[wp.zeros((1, 1), dtype=wp.float64, device=self.device, requires_grad=True)
                                   for _ in range(stages)],
                           points=[vec((2, 1, V)) for _ in range(stages - 1)],
                           accel=[vec((1, V)) for _ in range(stages - 1)])

    def _lane(self) -> Lane:
        E = len(self.host.hinges)
        return Lane(edge=wp.zeros((4, 1, E), dtype=self.scalar, device=self.device, requires_grad=True),
                    air=wp.zeros(1, dtype=wp.float64, device=self.device, requires_grad=True),
                    step_h=wp.zeros(1, dtype=self.scalar, device=self.device), work=self._work_buffers(),
                    controls=self.fam.controls(), jam=self.fam.jam_fields())

    @property
    def lane(self) -> Lane:
        """The adjoint's lane (lane 0)."""
        return self.lanes[0]

    def _work_buffers(self) -> StepBuffers:
        """One internal step's buffers as views of one rows array and one volumes array."""
        V, stages = len(self.host.rest_vertices), self._stages
        rows = self._vec((5 * stages - 1, 1, V))
        volumes = wp.zeros((stages, 1, 1), dtype=wp.float64, device=self.device, requires_grad=True)
        fg0, pts0, acc0 = 2, 2 + 2 * stages, 4 * stages
        return StepBuffers(xv_in=rows[0:2], xv_out=self._vec((2, 1, V)),
                           fg=[rows[fg0 + 2 * s:fg0 + 2 * s + 2] for s in range(stages)],
                           volume=[volumes[s] for s in range(stages)],
                           points=[rows[pts0 + 2 * s:pts0 + 2 * s + 2] for s in range(stages - 1)],
                           accel=[rows[acc0 + s] for s in range(stages - 1)], rows=rows, volumes=volumes,
                           kept=4 * stages)

    def _tape(self, slots: int, index: int = 0) -> "Tape":
        """Tape ``index`` (0 or 1), of at least ``slots`` internal steps (a new one drops the graphs of
        the old)."""
        tape = self.tapes[index]
        if tape is None or tape.slots < slots:
            self._graphs.clear()
            V, E, kept = len(self.host.rest_vertices), len(self.host.hinges), self.lane.work.kept
            tape = self.tapes[index] = Tape(
                rows=wp.zeros((slots, kept, V), dtype=self.vec3, device=self.device),
                volumes=wp.zeros((slots, self._stages), dtype=wp.float64, device=self.device),
                angles=wp.zeros((slots, self._stages, E), dtype=self.scalar, device=self.device),
                slot=wp.zeros(1, dtype=wp.int32, device=self.device))
        return tape

    # ------------------------------------------------------------------ launches
    def _build(self, launch) -> None:
        """The model arrays from the parameters (recorded on the build tape)."""
        h, V, E = self.host, len(self.host.rest_vertices), len(self.host.hinges)
        self.mass.zero_()
        self.fam.build(self.rest, launch)
        launch(ka.build_edges_kernel, E, [self.hinges, self.stretch_modulus, self.bending_stiffness, self.wing_scale,
                                          self.plate, int(self.design.material.hyperelastic), self.rest, self.edge0])
        launch(ka.build_mass_kernel, len(h.faces), [self.faces, self.scalar(self.design.material.areal_density),
                                                    self.rest, self.mass])
        launch(ka.invert_kernel, V, [self.mass, self.inv_mass])
        launch(ka.start_state_kernel, V, [self.rest, self.xv0])

    def _simulator_arrays(self) -> None:
        """The built model arrays replaced by the simulator's own (the host model's, in this precision), which
        the build gives within rounding at the design's parameters: the forward then rounds as the
        simulator does, bit for bit, and the build's adjoint (which reads its inputs, not these) is unchanged."""
        h = self.host
        self._set(self.edge0, np.stack([h.rest_length, h.rest_angle, h.edge_stiffness, h.bend_stiffness]))
        self._set(self.mass, h.mass)
        self._set(self.inv_mass, (1.0 / h.mass).astype(self.np_dtype))
        self.fam.restore_arrays()

    def _forces(self, xv, fg, volume, stage: int, lane: Lane, tape: Tape, launch) -> None:
        m, V, E = self.design.material, len(self.host.rest_vertices), len(self.host.hinges)
        launch(ka.start_forces_kernel, V, [self.scalar(m.viscous_damping), xv, fg, volume])
        launch(ka.hinge_grad_kernel, E, [self.hinges, self.owns, self.scalar(m.spring_damping), self.paper_bending,
                                         1, E, lane.edge, xv, 0, fg, volume, tape.angles, tape.slot, stage])
        self.fam.forces(lane.controls, xv, fg, launch, lane.state)  # the simulator's launches of the other families

    def _step(self, b: StepBuffers, launch, lane: Lane | None = None, tape: Tape | None = None) -> None:
        """One internal step (h: the lane's ``step_h``) from b.xv_in into b.xv_out, the hinges' angles
        into the tape's slot in hand (lane 0 and tape 0 where not given)."""
        V = len(self.host.rest_vertices)
        lane, tape = lane or self.lane, tape or self.tapes[0]
        gas = (wp.float64(self.host.gas_rt), wp.float64(self.host.atmospheric_pressure))
        if self.integrator != "rk4":
            self._forces(b.xv_in, b.fg[0], b.volume[0], 0, lane, tape, launch)
            launch(ka.semi_implicit_grad_kernel, V, [self.inv_mass, *gas, lane.step_h, lane.air, b.xv_in,
                                                      b.fg[0], b.volume[0], b.xv_out])
            return
        points = [b.xv_in] + b.points
        for s, c in enumerate((0.5, 0.5, 1.0)):
            self._forces(points[s], b.fg[s], b.volume[s], s, lane, tape, launch)
            launch(ka.rk4_point_kernel, V, [self.inv_mass, *gas, lane.step_h, self.scalar(c), lane.air, b.xv_in,
                                             points[s],
                                             b.fg[s], b.volume[s], b.accel[s], points[s + 1]])
        self._forces(points[3], b.fg[3], b.volume[3], 3, lane, tape, launch)
        launch(ka.rk4_combine_kernel, V, [self.inv_mass, *gas, lane.step_h, lane.air, b.xv_in, *b.points,
                                           *b.accel, b.fg[3], b.volume[3], b.xv_out])

    def kernel_launches(self) -> list:
        """(kernel, dim, inputs) of every launch the adjoint's forward makes: the build, one internal
        step, the tape's and a jam event (their adjoints take the same arguments), and the hinge pass's
        hand-written adjoint; e.g. to compile them."""
        step = self._record(lambda launch: self._step(self.single, launch))
        hinge = [hinge_adjoint_launch(dim, inputs) for kernel, dim, inputs in step if kernel is ka.hinge_grad_kernel]
        hand = {launch[0]: launch for launch in (adjoint_launch(*x) for x in step) if launch is not None}
        return (self._record(self._build) + step + self._tape_launches(store=True) + self._tape_launches(store=False)
                + hinge[:1] + list(hand.values()) + self._jam_launches())

    def _tape_launches(self, store: bool, lane: Lane | None = None, tape: Tape | None = None) -> list:
        """Store the lane's work buffers' intermediates in the tape's slot in hand and move to the next,
        or move back and load them (lane 0 and tape 0 where not given)."""
        w, V = (lane or self.lane).work, len(self.host.rest_vertices)
        t = tape or self.tapes[0]
        if store:
            return [(ka.tape_store_kernel, V, [t.slot, w.rows, w.volumes, t.rows, t.volumes]),
                    (ka.advance_slot_kernel, 1, [1, t.slot])]
        return [(ka.advance_slot_kernel, 1, [-1, t.slot]),
                (ka.tape_load_kernel, V, [t.slot, t.rows, t.volumes, w.rows, w.volumes])]

    # ------------------------------------------------------------------ recorded launches and graphs
    def _record(self, fill) -> list:
        """The launches ``fill(launch)`` makes, as (kernel, dim, inputs)."""
        out = []
        fill(lambda kernel, dim, inputs: out.append((kernel, dim, list(inputs))))
        return out

    def _run(self, launches, adjoint: bool = False) -> None:
        """Launch recorded launches forward, or their adjoints in reverse order."""
        if not adjoint:
            for kernel, dim, inputs in launches:
                wp.launch(kernel, dim, inputs, device=self.device, record_tape=False)
            return
        for kernel, dim, inputs in reversed(launches):
            if kernel is ka.hinge_grad_kernel:  # its adjoint is written by hand
                wp.launch(*hinge_adjoint_launch(dim, inputs), device=self.device, record_tape=False)
                continue
            hand = adjoint_launch(kernel, dim, inputs)  # the integrator's, written by hand too
            if hand is not None:
                wp.launch(*hand, device=self.device, record_tape=False)
                continue
            wp.launch(kernel, dim, inputs, adj_inputs=[adjoint_argument(a) for a in inputs], device=self.device,
                      adjoint=True, record_tape=False)

    def _capture(self, fill):
        with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            fill()
        return capture.graph

    def _single_graph(self):
        """The captured forward of one internal step on the single buffers."""
        if "single" not in self._graphs:
            launches = self._record(lambda launch: self._step(self.single, launch))
            self._graphs["single"] = self._capture(lambda: self._run(launches))
        return self._graphs["single"]

    def _forward_graph(self, lane: Lane, tape: Tape):
        """The captured forward of one internal step on the lane's work buffers: it steps work.xv_in
        into work.xv_out, leaves its intermediates in the tape's slot, moves to the next slot and makes
        xv_out the next step's xv_in."""
        key = ("forward", id(lane), id(tape))
        if key not in self._graphs:
            w = lane.work
            launches = self._record(lambda launch: self._step(w, launch, lane, tape)) + \
                self._tape_launches(True, lane, tape)

            def forward():
                self._run(launches)
                wp.copy(w.xv_in, w.xv_out)
            self._graphs[key] = self._capture(forward)
        return self._graphs[key]

    def _adjoint_graph(self, tape: Tape):
        """The captured adjoint of one internal step on lane 0: it moves back a slot of the tape, loads
        its intermediates, zeroes their adjoints, runs the step's adjoints (work.xv_out.grad in; the
        adjoints of the parameters, edge fields and controls add up) and leaves the adjoint of the state
        before the step in work.xv_out.grad, for the step before."""
        key = ("adjoint", id(tape))
        if key not in self._graphs:
            lane, w = self.lane, self.lane.work
            launches = self._record(lambda launch: self._step(w, launch, lane, tape))
            load = self._tape_launches(False, lane, tape)

            def adjoint():
                self._run(load)
                w.rows.grad.zero_()
                w.volumes.grad.zero_()
                self._run(launches, adjoint=True)
                wp.copy(w.xv_out.grad, w.xv_in.grad)
            self._graphs[key] = self._capture(adjoint)
        return self._graphs[key]

    # ------------------------------------------------------------------ forward and backward
    def forward(self, plan: ReplayPlan | None = None) -> ReplayPlan:
        """Replay on the simulator and keep the plan (schedule, checkpoints, jam phases); ``plan``: the
        one ``plan_replay`` made already for this design and result in this precision (nothing replayed)."""
        if plan is None:
            plan = plan_replay(self.design, self.result, precision=self.precision, device=self.device,
                               segment=self.segment)
        elif plan.precision != self.precision or plan.final.shape != (len(self.host.rest_vertices), 3):
            raise DesignError(f"the replay plan is of another precision ({plan.precision}) or mesh than this "
                              f"{self.precision} replay's: make it with plan_replay on the same design and result")
        self.plan = plan
        for lane in self.lanes:
            lane.loaded[:] = [None, None, None]
        return self.plan

    def _set(self, arr: wp.array, value) -> None:
        arr.assign(np.asarray(value, dtype=arr.numpy().dtype).reshape(arr.numpy().shape))

    def _controls(self, row: int, lane: Lane) -> None:
        """The controls of history row ``row`` (nothing to do where they are loaded already)."""
        if lane.loaded[1] == row:
            return
        lane.air.fill_(float(self.plan.air[row]))
        self._set_controls(lane, row, self._control_rows())
        lane.loaded[1] = row

    def _control_rows(self, given: dict | None = None) -> dict:
        """{family: (R, n)} every controlled family's controls per history row (the IPAM's: the plan's
        pressures), or ``given``'s ({gradient name: (R, n)}, e.g. ``ipam_pressures``) where given."""
        p, given = self.plan, given or {}
        rows = {}
        for fam in self.fam.controlled:
            plan_rows = p.pressures if fam.name == "ipam" else p.family_controls[fam.name]
            rows[fam.name] = np.asarray(given.get(controls_gradient_name(fam), plan_rows), dtype=np.float64)
        return rows

    def _set_controls(self, lane: Lane, row: int, rows: dict) -> None:
        """Row ``row`` of ``rows`` ({family: (R, n)}) into the lane's controls, with the masks."""
        for name, values in rows.items():
            self._set(lane.controls.values[name], values[row])
            if name == "ipam":
                self._set(lane.controls.enabled[name], self.plan.enabled)

    def _recompute(self, start: int, stop: int, lane: Lane | None = None, tape: Tape | None = None) -> None:
        """Output steps start..stop-1 recomputed from the checkpoint at start on ``lane``, every internal
        step's intermediates left on ``tape`` (slots 0, 1, ...; lane 0 and tape 0 where not given)."""
        p, lane = self.plan, lane or self.lane
        tape = tape or self._tape(int(p.substeps[start:stop].sum()))
        forward = self._forward_graph(lane, tape)
        self._set(lane.work.xv_in, p.checkpoints[start].reshape(2, 1, -1, 3))
        tape.slot.zero_()
        for k in range(start, stop):
            self._load_step(k, lane)
            for _ in range(int(p.substeps[k])):
                wp.capture_launch(forward)

    def _load_step(self, k: int, lane: Lane) -> None:
        """The edge fields, controls and internal step of output step k into ``lane``."""
        p = self.plan
        self._load_edges(self._phase_of(k), lane)
        self._controls(int(p.row[k]), lane)
        if lane.loaded[2] != p.h[k]:
            lane.step_h.fill_(float(p.h[k]))
            lane.loaded[2] = p.h[k]

    def _phase_of(self, k: int) -> int:
        """The jam phase of output step k (0 before the first jam event)."""
        return int(np.searchsorted(self.plan.jam_steps, k, side="right"))

    def _load_edges(self, phase: int, lane: Lane) -> None:
        """The edge fields and the families' jam fields of jam phase ``phase`` into ``lane``."""
        if lane.loaded[0] != phase:
            self._set(lane.edge, self.plan.edges[phase].reshape(4, 1, -1))
            ReplayFamilies.set_jam(lane.jam, self.plan.family_jams[phase])
            lane.loaded[0] = phase

    def _jam_launches(self) -> list:
        """A jam event's launches: the edges', then every jamming family's (``ForceFamily.jam_event``)."""
        E = len(self.host.hinges)
        m = self.design.material
        edges = (ka.jam_grad_kernel, E, [self.hinges, self.jam_now, self.scalar(m.jam_stretch_factor),
                                         self.scalar(m.jam_bend_factor), self.xv_jam, self.edge_before,
                                         self.edge_after])
        return [edges] + self._record(lambda launch: self.fam.jam(self.fam_before, self.fam_after, self.fam_now,
                                                                  self.xv_jam[0], launch))

    def _jam_mask(self, event: int) -> None:
        mask = np.zeros(len(self.host.hinges), dtype=np.int32)
        mask[self.plan.jam_edges[event]] = 1
        self.jam_now.assign(mask)
        for name, now in self.fam_now.items():
            now.assign(self.plan.family_jam_now[event][name])

    def _jam_adjoint(self, event: int, lam: wp.array) -> None:
        """Back through jam event ``event``: lane 0's edge.grad (the adjoint of the edges after it)
        becomes the adjoint of the edges before it, and the state it froze at gains its share in ``lam``."""
        p, lane = self.plan, self.lane
        self._jam_mask(event)
        self._set(self.edge_before, p.edges[event].reshape(4, 1, -1))
        self._set(self.xv_jam, p.jam_states[event].reshape(2, 1, -1, 3))
        ReplayFamilies.set_jam(self.fam_before, p.family_jams[event])
        launch = self._jam_launches()
        self._run(launch)
        wp.copy(self.edge_after.grad, lane.edge.grad)
        _copy_fields(self.fam_after, lane.jam, grad=True)
        self.edge_before.grad.zero_()
        _zero_field_grads(self.fam_before)
        self.xv_jam.grad.zero_()
        self._run(launch, adjoint=True)
        _add(lam, self.xv_jam.grad)
        wp.copy(lane.edge.grad, self.edge_before.grad)
        _copy_fields(lane.jam, self.fam_before, grad=True)
        self._load_edges(event, lane)

    def _zero_grads(self) -> None:
        lane = self.lane
        for a in (self.rest, self.stretch_modulus, self.bending_stiffness, self.edge0, self.mass, self.inv_mass,
                  self.xv0, lane.edge, lane.air, *lane.controls.values.values(), *self.fam.grad_arrays()):
            a.grad.zero_()
        for fields in (lane.jam, self.fam_before, self.fam_after):
            _zero_field_grads(fields)

    def _pipelined(self, threads: int | None, segments: int) -> bool:
        """Whether the backward recomputes the next segment on a second thread while it steps back
        through this one: ``threads`` 2 (or None: on a CPU device where this process may use two cores
        or more and is not a run's worker, whose siblings use the others) and more than one segment.
        Warp's CPU kernels run on the calling thread, outside Python's lock, so the two passes run on
        two cores."""
        if segments < 2:
            return False
        if threads is None:
            return wp.get_device(self.device).is_cpu and available_cores() >= 2 and not in_worker()
        return int(threads) >= 2

    def backward(self, dloss_dx, loss: float = 0.0, threads: int | None = None) -> ReplayGradient:
        """Every parameter's gradient from d(loss)/d(final positions) ``dloss_dx`` (V, 3). ``threads``:
        1 recomputes each segment and then steps back through it on this thread; 2 recomputes the next
        segment on a second thread meanwhile (the same arithmetic, so the same gradient bit for bit);
        None: 2 on a CPU with two cores or more (not in a run's worker)."""
        if self.plan is None:
            self.forward()
        p = self.plan
        build = self._record(self._build)
        self._run(build)
        self._simulator_arrays()
        self._zero_grads()
        lam = wp.zeros((2, 1, len(self.host.rest_vertices)), dtype=self.vec3, device=self.device)
        lam_np = np.zeros((2, 1, len(self.host.rest_vertices), 3))
        lam_np[0, 0] = np.asarray(dloss_dx, dtype=np.float64).reshape(-1, 3)
        self._set(lam, lam_np)
        adj_air = np.zeros(len(p.air))
        adj_f = {name: np.zeros(rows.shape) for name, rows in self._control_rows().items()}
        starts = sorted(p.checkpoints)
        events = {s: j for j, s in enumerate(p.jam_steps)}
        segments = list(reversed(list(zip(starts, starts[1:] + [p.n_steps]))))
        slots = max(int(p.substeps[a:b].sum()) for a, b in segments)
        pipelined = self._pipelined(threads, len(segments))
        if pipelined and len(self.lanes) < 2:
            self.lanes.append(self._lane())
        tapes = [self._tape(slots, 0)] + ([self._tape(slots, 1)] if pipelined else [])
        recompute_lane = self.lanes[1] if pipelined else self.lane
        adjoints = [self._adjoint_graph(t) for t in tapes]
        for t in tapes:
            self._forward_graph(recompute_lane, t)  # captured here, not on the second thread
        lane, w = self.lane, self.lane.work
        if pipelined:
            self._recompute(*segments[0], recompute_lane, tapes[0])
        for i, (start, stop) in enumerate(segments):
            tape = tapes[i % len(tapes)]
            worker = None
            if not pipelined:
                self._recompute(start, stop, lane, tape)
            elif i + 1 < len(segments):
                worker = _Worker(self._recompute, *segments[i + 1], recompute_lane, tapes[(i + 1) % 2])
            try:
                wp.copy(w.xv_out.grad, lam)
                tape.slot.fill_(int(p.substeps[start:stop].sum()))
                for k in reversed(range(start, stop)):
                    self._load_step(k, lane)
                    for _ in range(int(p.substeps[k])):
                        wp.capture_launch(adjoints[i % len(tapes)])
                    adj_air[p.row[k]] += float(lane.air.grad.numpy()[0])
                    lane.air.grad.zero_()
                    for name, adj in adj_f.items():
                        grad = lane.controls.values[name].grad
                        adj[p.row[k]] += grad.numpy()[0, :adj.shape[1]]
                        grad.zero_()
                    if k in events:
                        self._jam_adjoint(events[k], w.xv_out.grad)
            finally:
                if worker is not None:
                    worker.join()
            wp.copy(lam, w.xv_out.grad)
        wp.copy(self.edge0.grad, lane.edge.grad)
        wp.copy(self.xv0.grad, lam)
        self._run(build, adjoint=True)
        return ReplayGradient(loss=float(loss), values=self._values(adj_air, adj_f))

    def _values(self, adj_air: np.ndarray, adj_f: dict) -> dict:
        mat, rows = self.design.material, len(self.plan.air)
        g = lambda a: a.grad.numpy().astype(np.float64)  # noqa: E731
        stretch = float(g(self.stretch_modulus)[0])
        out = dict(rest_positions=g(self.rest).reshape(-1, 3), stretch_modulus=stretch,
                   youngs_modulus=stretch * mat.thickness, bending_stiffness=float(g(self.bending_stiffness)[0]),
                   air=adj_air, ipam_stiffness=np.zeros(0), ipam_area=np.zeros(0), ipam_pressures=np.zeros((rows, 0)))
        out.update(self.fam.parameter_gradients())
        for fam in self.fam.controlled:
            out[controls_gradient_name(fam)] = adj_f[fam.name]
        return out

    # ------------------------------------------------------------------ forward on the kernels alone
    def positions(self, rest=None, stretch_modulus=None, bending_stiffness=None, ipam_stiffness=None,
                  ipam_area=None, air=None, ipam_pressures=None, families: dict | None = None) -> np.ndarray:
        """(V, 3) final positions of the replay on the plan's schedule with the backward-enabled kernels,
        parameters replaced where given (rest (V, 3) m, stretch modulus N/m, bending N m/rad, IPAM
        stiffness (n,) N/m and area (n,) m^2, air (R,) mol and IPAM pressures (R, n) Pa per row, any force
        family's parameters and controls per row by their gradient names in ``families``): the function
        ``backward`` differentiates, jams included (frozen at the state reached)."""
        if self.plan is None:
            self.forward()
        p, h = self.plan, self.host
        given = dict(families or {})
        given.update({k: v for k, v in (("ipam_stiffness", ipam_stiffness), ("ipam_area", ipam_area),
                                         ("ipam_pressures", ipam_pressures)) if v is not None})
        for arr, value, base in ((self.rest, rest, h.rest_vertices),
                                 (self.stretch_modulus, stretch_modulus, [self.design.material.stretch_modulus]),
                                 (self.bending_stiffness, bending_stiffness, [self.design.material.bending_stiffness])):
            self._set(arr, base if value is None else value)
        self.fam.set_parameters(given)
        rows_f = self._control_rows(given)
        rows_air = p.air if air is None else np.asarray(air, dtype=np.float64)
        self._run(self._record(self._build))
        if not (given.keys() & self.fam.parameter_names or any(v is not None for v in (rest, stretch_modulus,
                                                                                       bending_stiffness))):
            self._simulator_arrays()
        self.tapes[0].slot.zero_()
        lane = self.lane
        b = self.single
        wp.copy(b.xv_out, self.xv0)
        wp.copy(lane.edge, self.edge0)
        ReplayFamilies.set_jam(lane.jam, p.family_jams[0])
        events = {s: j for j, s in enumerate(p.jam_steps)}
        for k in range(p.n_steps):
            if k in events:
                self._jam_mask(events[k])
                wp.copy(self.xv_jam, b.xv_out)
                wp.copy(self.edge_before, lane.edge)
                _copy_fields(self.fam_before, lane.jam)
                self._run(self._jam_launches())
                wp.copy(lane.edge, self.edge_after)
                _copy_fields(lane.jam, self.fam_after)
            row = int(p.row[k])
            lane.air.assign(np.array([rows_air[row]]))
            self._set_controls(lane, row, rows_f)
            lane.step_h.fill_(float(p.h[k]))
            fwd = self._single_graph()
            for _ in range(int(p.substeps[k])):
                wp.copy(b.xv_in, b.xv_out)
                wp.capture_launch(fwd)
        lane.loaded[:] = [None, None, None]
        return b.xv_out.numpy()[0, 0].astype(np.float64)


def adjoint_argument(a):
    """The adjoint argument of a recorded launch input (as wp.Tape does)."""
    if isinstance(a, wp.array):
        return a.grad
    if wp.types.is_value(a) and not isinstance(a, (int, float, bool)):
        return type(a)()
    return None


def hinge_adjoint_launch(dim: int, inputs: list) -> tuple:
    """(kernel, dim, inputs) of the hinge pass's adjoint for a recorded hinge_grad_kernel launch: its
    inputs, the adjoints of its outputs (forces and dV/dx, volume) in, of the edges and state out."""
    *model, edge, xv, vslot, fg, volume, angles, slot, stage = inputs
    return ka.hinge_adjoint_kernel, dim, [*model, edge, xv, vslot, fg.grad, volume.grad, edge.grad, xv.grad, angles,
                                          slot, stage]


class _Worker(threading.Thread):
    """``call(*args)`` on a thread of its own, started at once; ``join`` re-raises what it raised."""

    def __init__(self, call, *args):
        super().__init__(daemon=True)
        self.call, self.args, self.error = call, args, None
        self.start()

    def run(self) -> None:
        try:
            self.call(*self.args)
        except BaseException as e:  # noqa: BLE001 - handed to the joining thread
            self.error = e

    def join(self, timeout=None) -> None:
        super().join(timeout)
        if self.error is not None:
            raise self.error


def _copy_fields(dst: dict, src: dict, grad: bool = False) -> None:
    """dst's jam fields = src's (their adjoints where ``grad``: the floating-point fields only)."""
    for name, arrays in dst.items():
        for k, a in arrays.items():
            if not grad:
                wp.copy(a, src[name][k])
            elif a.grad is not None:
                wp.copy(a.grad, src[name][k].grad)


def _zero_field_grads(fields: dict) -> None:
    for arrays in fields.values():
        for a in arrays.values():
            if a.grad is not None:
                a.grad.zero_()


def _add(dst: wp.array, src: wp.array) -> None:
    """dst += src (same shape and type)."""
    dst.assign(dst.numpy() + src.numpy())
