"""Design -> Model (static device arrays) / State / Control (per-world device arrays).

Many worlds share one Model: every State and Control array has a leading world dimension W, so the
controller can drive all targets of a design as one batch (one launch per kernel for all worlds).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from warp_shape.kernels import common as kc

from .display import Design
from .errors import DesignError
from .material import GAS_CONSTANT
from .force_family import families, force_families
from .step_plan import create_overloads
from .physics import ipam as ipam_family  # noqa: F401  (registers the IPAM family, the first)
from .physics import membrane as membrane_family  # noqa: F401  (registers the hyperelastic membrane family)
from .physics import contact as contact_family  # noqa: F401,I001  (registers the indenter and the hold)
from .physics.bending_law import dihedral_angles_np

__all__ = ["Model", "State", "Control", "WorldRef", "copy_worlds", "check_layout", "build_model", "check_device",
           "HostModel", "host_model", "hinge_bend_stiffness", "PRECISIONS", "cell_anchor_faces", "model_families"]

PRECISIONS = {
    "float32": (wp.float32, wp.vec3f, np.float32),
    "float64": (wp.float64, wp.vec3d, np.float64),
}


@dataclass
class Model:
    """Static arrays of a design on one device, in one precision. Shapes documented per field."""

    device: str
    precision: str
    n_vertices: int
    n_faces: int
    n_edges: int
    n_cells: int
    # material scalars (SI)
    spring_damping: float
    bending_stiffness: float  # the largest hinge k_t, N m/rad (HostModel.bend_stiffness holds each)
    viscous_damping: float
    jam_stretch_factor: float
    jam_bend_factor: float
    temperature: float
    atmospheric_pressure: float
    # device arrays
    faces: wp.array  # (F,) vec3i
    hinges: wp.array  # (E,) vec4i: v0, v1 (edge), v2, v3 (wings)
    hinge_owns: wp.array  # (E,) int32: bit 0 / bit 1 where the hinge owns face A / B (see face_owners)
    edge_stiffness: wp.array  # (E,) k_e, N/m
    inv_mass: wp.array  # (V,) 1/kg
    cell_edges: list  # n_cell x wp.array (n_c,) int32
    # host copies (float64) used for estimates, energies, observations and read-outs
    host: HostModel = field(repr=False)
    # force family name -> its device arrays (ForceFamily.device_arrays; empty without elements)
    actuators: dict = field(default_factory=dict, repr=False)

    # the IPAM family's device arrays (``actuators["ipam"]``; None without IPAMs)
    ipam_sub_pairs = property(lambda self: self.actuators["ipam"].get("sub_pairs"), doc="(3 n_ipam,) vec2i")
    ipam_sub_offsets = property(lambda self: self.actuators["ipam"].get("sub_offsets"), doc="(3 n_ipam,) m")
    ipam_stiffness = property(lambda self: self.actuators["ipam"].get("stiffness"), doc="(n_ipam,) N/m")
    ipam_area_over_k = property(lambda self: self.actuators["ipam"].get("area_over_k"), doc="(n_ipam,) m/Pa")
    ipam_free_length = property(lambda self: self.actuators["ipam"].get("free_length"), doc="(n_ipam,) m")
    ipam_damping = property(lambda self: self.actuators["ipam"].get("damping"), doc="(n_ipam,) N s/m")

    @property
    def families(self) -> tuple:
        """The model's force families besides the membrane's own (``HostModel.families``: its actuator
        families, then its passive ones)."""
        return self.host.families

    @property
    def n_ipams(self) -> int:
        return self.host.n_ipams

    @property
    def scalar(self):
        return PRECISIONS[self.precision][0]

    @property
    def vec3(self):
        return PRECISIONS[self.precision][1]

    @property
    def np_dtype(self):
        return PRECISIONS[self.precision][2]

    @property
    def gas_rt(self) -> float:
        return GAS_CONSTANT * self.temperature

    @property
    def has_bending(self) -> bool:
        return self.bending_stiffness > 0.0

    def state(self, worlds: int = 1, jam_from: State | None = None) -> State:
        """A new ``State`` of ``worlds`` worlds at rest (rest positions, zero velocities, nothing
        jammed); with ``jam_from`` it shares that state's jam fields (the same arrays) instead."""
        return State(self, worlds, jam_from)

    def control(self, worlds: int = 1, air_moles: float | None = None) -> Control:
        """A new ``Control`` of ``worlds`` worlds: ``air_moles`` (mol; the rest air when None), every
        actuator family at its rest controls (IPAM pressures zero), every element enabled."""
        return Control(self, worlds, self.host.rest_air if air_moles is None else air_moles)


def face_owners(topo) -> np.ndarray:
    """(E,) int32 bit mask giving every face to exactly one of its three hinges (the lowest edge
    index): bit 0 set where the hinge owns its face A, bit 1 where it owns face B. The fused hinge
    pass adds a face's volume and dV/dx only from its owner."""
    owner = topo.face_edges.min(axis=1)  # (F,)
    e = np.arange(topo.count)
    return ((owner[topo.faces[:, 0]] == e) * 1 + (owner[topo.faces[:, 1]] == e) * 2).astype(np.int32)


def cell_anchor_faces(design: Design) -> np.ndarray:
    """(n_cell,) the face of each cell whose radius is the curvature reference r_IPAM: the IPAM end
    inside the cell, else the face whose centroid direction is closest to the cell's mean direction."""
    ends = {}
    for ip in design.ipams:
        for f in (ip.face_a, ip.face_b):
            ends.setdefault(int(f), True)
    c = design.rest.face_centroids()
    anchors = np.empty(design.n_cells, dtype=np.int64)
    for j, cell in enumerate(design.cells):
        inside = [f for f in cell.faces.tolist() if f in ends]
        if inside:
            anchors[j] = inside[0]
        else:
            u = c[cell.faces] / np.linalg.norm(c[cell.faces], axis=1, keepdims=True)
            anchors[j] = cell.faces[int(np.argmax(u @ u.mean(axis=0)))]
    return anchors


@dataclass(frozen=True)
class HostModel:
    """Host (float64 / int64) arrays of a design, built once per Simulator: rest geometry, stiffness,
    mass, IPAMs, cells and the gas constants. Shared by the device model, the storability check, the
    energies, the stable-step estimate, the controller (observations, laws, plans) and the NumPy
    baseline. E edges (hinges), F faces, V vertices, n IPAMs, c cells."""

    rest_vertices: np.ndarray  # (V, 3) m
    faces: np.ndarray  # (F, 3) int64
    hinges: np.ndarray  # (E, 4) int64: v0, v1 (edge), v2, v3 (wings)
    hinge_faces: np.ndarray  # (E, 2) int64: face A, face B of each hinge
    hinge_owns: np.ndarray  # (E,) int32 bit mask (see face_owners)
    rest_length: np.ndarray  # (E,) m
    rest_angle: np.ndarray  # (E,) rad
    edge_stiffness: np.ndarray  # (E,) k_e, N/m (0 with a hyperelastic membrane: the triangles carry it)
    bend_stiffness: np.ndarray  # (E,) k_t, N m/rad (Material.bending_stiffness, or the plate's hinge weighting)
    mass: np.ndarray  # (V,) kg
    cell_edges: list  # n_cell x (n_c,) int32 edge indices
    cell_faces: list  # n_cell x (n_c,) int64 face indices
    cell_anchors: np.ndarray  # (c,) int64: each cell's curvature reference face (see cell_anchor_faces)
    gas_rt: float  # R T, J/mol
    atmospheric_pressure: float  # Pa absolute
    rest_air: float  # mol: the air that holds the rest volume at atmospheric pressure
    families: tuple = ()  # the model's force families (ActuatorFamily, then passive ForceFamily), in the order their forces add
    actuators: dict = field(default_factory=dict)  # family name -> its host arrays (ActuatorFamily.host_arrays)

    # the IPAM family's host arrays (``actuators["ipam"]``), n IPAMs
    ipam_faces = property(lambda self: self.actuators["ipam"]["faces"],
                          doc="(n, 2) int64: end faces a, b")
    ipam_sub_pairs = property(lambda self: self.actuators["ipam"]["sub_pairs"],
                              doc="(3 n, 2) int64: vertex of face a, vertex of face b")
    ipam_sub_offsets = property(lambda self: self.actuators["ipam"]["sub_offsets"], doc="(3 n,) m")
    ipam_stiffness = property(lambda self: self.actuators["ipam"]["stiffness"], doc="(n,) k, N/m")
    ipam_area_over_k = property(lambda self: self.actuators["ipam"]["area_over_k"], doc="(n,) A / k, m/Pa")
    ipam_free_length = property(lambda self: self.actuators["ipam"]["free_length"], doc="(n,) L0, m")
    ipam_damping = property(lambda self: self.actuators["ipam"]["damping"], doc="(n,) N s/m per sub-spring")
    ipam_limits = property(lambda self: self.actuators["ipam"]["limits"], doc="(n, 2) Pa gauge: P_min, P_max")

    @property
    def n_ipams(self) -> int:
        return len(self.ipam_faces)

    @property
    def actuator_families(self) -> tuple:
        """The model's families that take controls (``families`` less the passive ones)."""
        return tuple(f for f in self.families if f.controlled)

    def count(self, family: str) -> int:
        """Number of elements of actuator family ``family`` (0 when the model does not hold it)."""
        fam = next((f for f in self.families if f.name == family), None)
        return 0 if fam is None else len(fam.rest_controls(self.actuators[family]))

    @property
    def n_cells(self) -> int:
        return len(self.cell_faces)


def host_model(design: Design) -> HostModel:
    """The float64/int64 host arrays of a design (see ``HostModel``)."""
    mesh, mat = design.rest, design.material
    topo = mesh.topology
    x = mesh.vertices
    hinges = topo.hinges
    areas = mesh.face_areas()
    rest_length = np.linalg.norm(x[hinges[:, 1]] - x[hinges[:, 0]], axis=1)
    if design.stretch_scale is not None:  # E t per face (calibrated regions)
        areas = areas * design.stretch_scale
    hinge_area = areas[topo.faces[:, 0]] + areas[topo.faces[:, 1]]
    fams = model_families(design)
    return HostModel(
        rest_vertices=x, faces=mesh.faces.astype(np.int64), hinges=hinges.astype(np.int64),
        hinge_faces=topo.faces.astype(np.int64), hinge_owns=face_owners(topo),
        rest_length=rest_length, rest_angle=dihedral_angles_np(x, hinges),
        edge_stiffness=(0.0 if mat.hyperelastic else mat.stretch_modulus) * hinge_area / rest_length**2,
        bend_stiffness=hinge_bend_stiffness(mat, rest_length, mesh.face_areas(), topo.faces),
        mass=mat.areal_density * mesh.vertex_areas(),
        cell_edges=[design.cell_edges(c) for c in range(design.n_cells)],
        cell_faces=[c.faces.astype(np.int64) for c in design.cells], cell_anchors=cell_anchor_faces(design),
        gas_rt=GAS_CONSTANT * mat.temperature, atmospheric_pressure=mat.atmospheric_pressure,
        rest_air=mat.atmospheric_pressure * mesh.volume() / (GAS_CONSTANT * mat.temperature),
        families=fams, actuators={f.name: f.host_arrays(design) for f in fams},
    )


def hinge_bend_stiffness(mat, rest_length: np.ndarray, face_areas: np.ndarray, hinge_faces: np.ndarray) -> np.ndarray:
    """(E,) k_t in N m/rad of every hinge: the paper's ``bending_stiffness`` on all hinges with
    ``membrane="springs"``; else the plate stiffness D = E t^3 / 12 (1 - nu^2) (``Material.plate_stiffness``)
    through the discrete-shell weighting k_t = 3 D |e|^2 / A_e (A_e the rest area of the hinge's two faces),
    whose energy 0.5 k_t theta^2 summed over a fine mesh bent to a sphere of radius R is D/2 (2/R)^2 per area."""
    if not mat.hyperelastic:
        return np.full(rest_length.shape, mat.bending_stiffness)
    hinge_area = face_areas[hinge_faces[:, 0]] + face_areas[hinge_faces[:, 1]]
    return 3.0 * mat.plate_stiffness * rest_length ** 2 / hinge_area


def model_families(design: Design) -> tuple:
    """The force families a model of ``design`` holds besides the membrane's own: every registered
    actuator family that is ``always`` held or has elements in the design, then every registered
    passive force family (``FORCE_FAMILIES``) with elements, each in registration order."""
    return (tuple(f for f in families() if f.always or f.count(design))
            + tuple(f for f in force_families() if f.count(design)))


def check_device(device) -> str:
    """The Warp name of ``device``; an unavailable device raises ``DesignError`` listing those here."""
    try:
        return str(wp.get_device(device))
    except Exception as exc:
        have = ", ".join(str(d) for d in wp.get_devices())
        raise DesignError(f"device {device!r} is not available ({exc}); devices here: {have}") from None


def build_model(design: Design, device: str = "cpu", precision: str = "float32",
                host: HostModel | None = None) -> Model:
    """Build the static device arrays of a design (host -> device, once) from its host model
    (``host_model(design)`` when None)."""
    if precision not in PRECISIONS:
        raise DesignError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    scalar, _, np_dtype = PRECISIONS[precision]
    mesh, mat = design.rest, design.material
    topo = mesh.topology
    host = host_model(design) if host is None else host
    hinges, stiffness, mass = host.hinges, host.edge_stiffness, host.mass

    def arr(a, dtype=None):
        if dtype is None:
            a, dtype = np.asarray(a).astype(np_dtype), scalar
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)

    device_arrays = {f.name: f.device_arrays(host.actuators[f.name], arr) if f.count(design) else {}
                     for f in host.families}
    cell_edges_np = host.cell_edges

    return Model(
        device=str(device), precision=precision,
        n_vertices=mesh.n_vertices, n_faces=mesh.n_faces, n_edges=topo.count,
        n_cells=design.n_cells,
        spring_damping=mat.spring_damping, bending_stiffness=float(host.bend_stiffness.max(initial=0.0)),
        viscous_damping=mat.viscous_damping, jam_stretch_factor=mat.jam_stretch_factor,
        jam_bend_factor=mat.jam_bend_factor, temperature=mat.temperature,
        atmospheric_pressure=mat.atmospheric_pressure,
        faces=arr(mesh.faces.astype(np.int32), wp.vec3i),
        hinges=arr(hinges.astype(np.int32), wp.vec4i),
        hinge_owns=arr(host.hinge_owns, wp.int32),
        edge_stiffness=arr(stiffness.astype(np_dtype)),
        inv_mass=arr((1.0 / mass).astype(np_dtype)),
        cell_edges=[arr(c.astype(np.int32), wp.int32) for c in cell_edges_np],
        host=host, actuators=device_arrays,
    )


class State:
    """Per-world state: positions and velocities (what a step advances) and the jam fields (what a
    jam changes and a step only reads). Allocated by ``Model.state``.

    The step kernels take few, packed arrays (on CPU every array argument costs loads on every
    element), so related fields share one buffer and the named fields are views into it:
    ``xv`` (2, W, V) holds positions ``x`` and velocities ``v``; ``edge`` (4, W, E) holds each edge's
    ``rest_length`` (m), ``rest_angle`` (rad), ``stretch_stiffness`` (N/m) and ``bend_stiffness``
    (N m/rad), the last two already multiplied by the jam factors where the edge is jammed.
    The jam fields are ``edge``, ``jammed``, the families' ``family_jam`` (``ForceFamily.jam_fields``: the
    hyperelastic membrane's triangles) and the host arrays ``cell_jammed``, ``cell_jam_time`` and
    ``cell_enabled``; ``jam_from`` (a state of the same model and worlds) makes them that state's.
    """

    def __init__(self, model: Model, worlds: int, jam_from: State | None = None):
        dev, vec3, np_dtype = model.device, model.vec3, model.np_dtype
        W, V, E = worlds, model.n_vertices, model.n_edges
        xv = np.zeros((2, W, V, 3), dtype=np_dtype)
        xv[0] = model.host.rest_vertices
        self.worlds = W
        self._set_xv(wp.array(xv, dtype=vec3, device=dev))
        if jam_from is not None:
            if jam_from.worlds != W:
                raise ValueError(f"jam_from has {jam_from.worlds} worlds, this state {W}")
            self.share_jam(jam_from)
            return
        h = model.host
        edge = np.empty((4, W, E), dtype=np_dtype)
        edge[0], edge[1] = h.rest_length, h.rest_angle
        edge[2], edge[3] = h.edge_stiffness, h.bend_stiffness
        families = {f.name: f.jam_fields(model, W) for f in model.families if f.jams and model.host.count(f.name)}
        self._set_jam(wp.array(edge, dtype=model.scalar, device=dev), wp.zeros((W, E), dtype=wp.int32, device=dev),
                      np.zeros((W, model.n_cells), dtype=bool), np.full((W, model.n_cells), np.nan),
                      np.ones((W, model.n_cells), dtype=bool), families)

    def _set_xv(self, xv: wp.array) -> None:
        self.xv = xv  # (2, W, V): x (m), v (m/s)
        self.x = self.xv[0]  # (W, V) m
        self.v = self.xv[1]  # (W, V) m/s

    def _set_jam(self, edge, jammed, cell_jammed, cell_jam_time, cell_enabled, families) -> None:
        self.edge = edge  # (4, W, E)
        self.rest_length = self.edge[0]  # (W, E) m
        self.rest_angle = self.edge[1]  # (W, E) rad
        self.stretch_stiffness = self.edge[2]  # (W, E) N/m, jam factor applied
        self.bend_stiffness = self.edge[3]  # (W, E) N m/rad, jam factor applied
        self.jammed = jammed  # (W, E) int32, 1 where jammed
        self.cell_jammed = cell_jammed  # host mirror, (W, n_cell) bool
        self.cell_jam_time = cell_jam_time  # (W, n_cell) s, NaN where not jammed
        self.cell_enabled = cell_enabled  # (W, n_cell) bool, False: the cell never jams there
        self.family_jam = families  # family name -> {field: device array}: ForceFamily.jam_fields of a family that jams

    def clone(self) -> State:
        """A copy of this state with jam fields of its own (device arrays copied on the device)."""
        out = State.__new__(State)
        out.worlds = self.worlds
        out._set_xv(wp.clone(self.xv))
        out._set_jam(wp.clone(self.edge), wp.clone(self.jammed), self.cell_jammed.copy(), self.cell_jam_time.copy(),
                     self.cell_enabled.copy(),
                     {k: {n: wp.clone(a) for n, a in f.items()} for k, f in self.family_jam.items()})
        return out

    def share_jam(self, other: State) -> None:
        """Make the jam fields ``other``'s (the same arrays: a jam of either is seen by both)."""
        self._set_jam(other.edge, other.jammed, other.cell_jammed, other.cell_jam_time, other.cell_enabled,
                      other.family_jam)

    def shares_jam(self, other: State) -> bool:
        """Whether this state's jam fields are ``other``'s."""
        return self.edge is other.edge and self.cell_jammed is other.cell_jammed


class Control:
    """Per-world controls: chamber air amount and, per actuator family of the model, one float64
    control per element (``values[name]`` (W, n); the IPAM's are gauge pressures, ``ipam_pressure``)
    and its mask (``enabled[name]`` (W, n) int32, 0 where an element is masked out of a world: no
    force there, so one model can hold alternative actuator sets and each world enable its own).
    A family without elements keeps a (W, 1) placeholder (valid arrays, never launched)."""

    def __init__(self, model: Model, worlds: int, air_moles: float):
        dev = model.device
        self.air = wp.array(np.full(worlds, air_moles, dtype=np.float64), dtype=wp.float64, device=dev)  # (W,) mol
        self.values, self.enabled = {}, {}
        for fam in model.families:
            rest = fam.rest_controls(model.host.actuators[fam.name])
            full = np.zeros((worlds, max(rest.size, 1)))
            full[:, : rest.size] = rest
            self.values[fam.name] = wp.array(full, dtype=wp.float64, device=dev)
            self.enabled[fam.name] = wp.array(np.ones(full.shape, dtype=np.int32), dtype=wp.int32, device=dev)

    @property
    def ipam_pressure(self) -> wp.array:
        """(W, n_ipam) IPAM gauge pressures, Pa."""
        return self.values["ipam"]

    @property
    def ipam_enabled(self) -> wp.array:
        """(W, n_ipam) int32 IPAM mask."""
        return self.enabled["ipam"]

    def clone(self) -> Control:
        """A copy of these controls (copied on the device)."""
        out = Control.__new__(Control)
        out.air = wp.clone(self.air)
        out.values = {k: wp.clone(a) for k, a in self.values.items()}
        out.enabled = {k: wp.clone(a) for k, a in self.enabled.items()}
        return out


@dataclass(frozen=True)
class WorldRef:
    """World ``world`` of a state and its control (a snapshot of a simulator: ``Simulator.snapshot``)."""

    state: State
    control: Control
    world: int


def check_layout(src: State, src_control: Control, dst: State, dst_control: Control) -> None:
    """Refuse a world copy between states (and controls) of different designs or precisions."""
    if src.xv.dtype != dst.xv.dtype or src.xv.shape[2] != dst.xv.shape[2] or src.edge.shape[2] != dst.edge.shape[2] \
            or {k: a.shape[1] for k, a in src_control.values.items()} \
            != {k: a.shape[1] for k, a in dst_control.values.items()}:
        raise DesignError("world copies go between states of one design in one precision; these differ "
                          f"({src.xv.shape[2]} vs {dst.xv.shape[2]} vertices, {src.xv.dtype.__name__} vs "
                          f"{dst.xv.dtype.__name__}): load worlds of a simulator of the same design and precision")


def copy_worlds(src: State, src_control: Control, src_worlds, dst: State, dst_control: Control, dst_worlds,
                device: str) -> None:
    """Copy worlds ``src_worlds`` (n,) of (src, src_control) into worlds ``dst_worlds`` (n,) of (dst,
    dst_control) on the device: positions, velocities, the jam fields of the edges, the air and every
    actuator family's controls (the IPAM pressures), and the host jam flags and times of the cells
    (the actuator and cell masks stay the destination's). A source world may go to several
    destinations; destinations must differ, and must not be read as a source of the same copy."""
    si = np.asarray(src_worlds, dtype=np.int64).reshape(-1)
    di = np.asarray(dst_worlds, dtype=np.int64).reshape(-1)
    if si.shape != di.shape or len(set(di.tolist())) != len(di):
        raise DesignError(f"copy_worlds needs one distinct destination per source world, got {si} -> {di}")
    if src is dst and set(si.tolist()) & set(di.tolist()):
        raise DesignError("copy_worlds within one state needs sources apart from destinations")
    check_layout(src, src_control, dst, dst_control)
    if np.any((si < 0) | (si >= src.worlds)) or np.any((di < 0) | (di >= dst.worlds)):
        raise DesignError(f"copy_worlds: worlds {si} -> {di} out of range (source has {src.worlds}, destination "
                          f"{dst.worlds})")
    if not len(si):
        return
    s_idx = wp.array(si.astype(np.int32), dtype=wp.int32, device=device)
    d_idx = wp.array(di.astype(np.int32), dtype=wp.int32, device=device)
    pairs = [(src.xv, dst.xv), (src.edge, dst.edge), (src.jammed, dst.jammed), (src_control.air, dst_control.air)]
    pairs += [(a, dst_control.values[k]) for k, a in src_control.values.items()]
    pairs += [(a, dst.family_jam[k][n]) for k, f in src.family_jam.items() for n, a in f.items()]
    launches = []
    for a, b in pairs:
        a3 = a if a.ndim == 3 else a.reshape((1, a.shape[0], -1))
        b3 = b if b.ndim == 3 else b.reshape((1, b.shape[0], -1))
        launches.append((kc.copy_worlds_kernel, (len(si), a3.shape[0], a3.shape[2]), [a3, s_idx, d_idx, b3]))
    create_overloads(launches)  # one per field type: the module loads once with them all
    for kernel, dim, inputs in launches:
        wp.launch(kernel, dim, inputs, device=device)
    dst.cell_jammed[di] = src.cell_jammed[si]
    dst.cell_jam_time[di] = src.cell_jam_time[si]
