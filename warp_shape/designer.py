"""Automatic design for a set of target shapes (paper section V, Algorithm 1; SPEC section 7).

``design(base, targets, actuators=p)``:
1. initialise (multi-target mode): centre the targets; sample every target radially through the
   base mesh's vertex directions; normalise each target's radii to unit volume, average them per
   vertex, and scale the result to ``volume_scale`` (0.8) x the smallest target's volume, so the
   membrane is in tension everywhere once inflated. Single-target mode (``initialize=False``) keeps
   the given rest shape (centred).
2. p rounds: control the current design to every target (one batch of worlds); compute the scaled
   radial error e = (R - r) / V_t^(1/3) at every face centroid (R: target sampled through the
   achieved face centroid, r: its radius); the free face (no cell, no IPAM end) with the largest
   |e| over all targets is one IPAM end; the other end is, in that target, the free face with the
   largest error of the same sign among faces at least ``min_angle`` (120 degrees) away seen from
   the origin; add the IPAM and a jamming cell of ``cell_radius`` around each end (faces whose rest
   centroids lie within the radius and are in no cell yet).
3. a final control run of the finished design: round p. ``pcc_by_round`` is (p + 1, n_targets).

Actuator selection (``select_actuators``, on by default; not in the paper's algorithm): when a new
actuator set lowers a target's PCC by more than ``max_drop``, that target is re-run with the new
set held neutral (IPAM natural length tracking its length, cells never jammed: the paper notes in
section V-C that an actuator can be neutralised this way) and the better run is kept. The control
sequence then records which actuators each target uses; ``added[k]["left_out_for"]`` lists them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .controller import ControlResult, ControlSettings, control_many
from .design import (DEFAULT_IPAM_AREA, DEFAULT_IPAM_DAMPING, DEFAULT_IPAM_PRESSURE_LIMITS, DEFAULT_IPAM_STIFFNESS,
                     Design)
from .errors import DesignError
from .material import Material
from .mesh import TriMesh
from .settings import replace_settings

__all__ = ["DesignSettings", "DesignResult", "design", "initial_rest_shape", "copy_design", "selection_to_settings",
           "selection_from_settings"]


@dataclass(frozen=True)
class DesignSettings:
    """Designer parameters (SI)."""

    cell_radius: float = 0.012  # m, jamming-cell radius around each IPAM end (rest-shape distance)
    volume_scale: float = 0.8  # rest volume / smallest target volume (multi-target initialisation)
    min_angle_deg: float = 120.0  # the two IPAM ends are at least this far apart seen from the origin
    initialize: bool = True  # False: keep the given rest shape (single-target mode)
    select_actuators: bool = True  # leave a new actuator set out of a target's sequence when it lowers that PCC
    max_drop: float = 0.005  # PCC drop that triggers the selection above
    ipam_stiffness: float = DEFAULT_IPAM_STIFFNESS  # N/m of every added IPAM
    ipam_area: float = DEFAULT_IPAM_AREA  # m^2
    ipam_damping: float = DEFAULT_IPAM_DAMPING  # N s/m
    ipam_pressure_limits: tuple = DEFAULT_IPAM_PRESSURE_LIMITS  # Pa gauge

    def __post_init__(self):
        if not (self.cell_radius > 0 and math.isfinite(self.cell_radius)):
            raise DesignError(f"cell_radius must be a positive length in m, got {self.cell_radius}")
        if not 0 < self.volume_scale <= 1:
            raise DesignError(f"volume_scale must be in (0, 1], got {self.volume_scale}")
        if not 0 < self.min_angle_deg < 180:
            raise DesignError(f"min_angle_deg must be in (0, 180), got {self.min_angle_deg}")


@dataclass
class DesignResult:
    """Everything the designer produced."""

    design: Design  # the final design
    designs: list  # D_0 .. D_p
    rounds: list  # rounds[i][j]: ControlResult of design D_i driven to target j
    pcc_by_round: np.ndarray  # (p + 1, n_targets)
    target_names: list
    targets: list  # centred targets (TriMesh)
    added: list = field(default_factory=list)  # per added actuator: round, target, faces, errors
    passive_ipams: list = field(default_factory=list)  # per target: IPAMs left out of its control sequence
    passive_cells: list = field(default_factory=list)  # per target: cells left out of its control sequence
    settings: DesignSettings = field(default_factory=DesignSettings)
    control_settings: ControlSettings = field(default_factory=ControlSettings)

    @property
    def results(self) -> list[ControlResult]:
        """One control result per target for the final design."""
        return self.rounds[-1]

    def selection_settings(self) -> dict:
        """Controller settings recording which actuators each target's sequence leaves out (flat
        string entries, as scene settings require): ``passive_ipams_<target>`` = "2 3"."""
        return selection_to_settings(self.target_names, self.passive_ipams, self.passive_cells)

    def report(self) -> dict:
        """The design outcome as a JSON-ready dict: PCC by round, actuators added, final fit, settings."""
        fin = self.results
        return dict(
            targets=self.target_names,
            actuators=self.design.n_ipams, cells=self.design.n_cells,
            vertices=self.design.rest.n_vertices,
            pcc_by_round=self.pcc_by_round.tolist(),
            final={name: r.summary() for name, r in zip(self.target_names, fin)},
            added=self.added,
            settings=dict(designer=asdict(self.settings), controller=asdict(self.control_settings)),
        )


def _setting_key(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def selection_to_settings(names, passive_ipams, passive_cells) -> dict:
    """Scene controller settings recording each target's passive IPAMs and cells (flat strings)."""
    out = {}
    for name, pi, pc in zip(names, passive_ipams, passive_cells):
        if pi:
            out[f"passive_ipams_{_setting_key(name)}"] = " ".join(str(int(i)) for i in pi)
        if pc:
            out[f"passive_cells_{_setting_key(name)}"] = " ".join(str(int(c)) for c in pc)
    return out


def selection_from_settings(settings: dict | None, names) -> tuple[list, list]:
    """Per-target passive IPAM and cell lists stored by ``selection_to_settings`` (empty if none)."""
    ctl = (settings or {}).get("controller", {})
    ipams = [[int(v) for v in str(ctl.get(f"passive_ipams_{_setting_key(n)}", "")).split()] for n in names]
    cells = [[int(v) for v in str(ctl.get(f"passive_cells_{_setting_key(n)}", "")).split()] for n in names]
    return ipams, cells


def copy_design(d: Design, rest: TriMesh | None = None) -> Design:
    """A new Design with the same (or a new) rest mesh, material, IPAMs and cells."""
    out = Design(rest if rest is not None else d.rest, d.material)
    for ip in d.ipams:
        out.add_ipam(ip.face_a, ip.face_b, stiffness=ip.stiffness, area=ip.area, free_length=None
                     if rest is not None else ip.free_length, pressure_limits=ip.pressure_limits, damping=ip.damping)
    for c in d.cells:
        out.add_cell(c.faces)
    return out


def _check_targets(targets, target_names):
    if isinstance(targets, TriMesh):
        targets = [targets]
    targets = list(targets)
    if not targets:
        raise DesignError("design needs at least one target shape")
    for t in targets:
        if not isinstance(t, TriMesh):
            raise DesignError(f"targets must be ws.TriMesh (e.g. ws.target('heart')), got {type(t).__name__}")
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(len(targets))]
    if len(names) != len(targets):
        raise DesignError(f"{len(names)} target names for {len(targets)} targets")
    if len(set(names)) != len(names):
        raise DesignError(f"duplicate target names {names}; give each target once")
    centred = [t.centered() for t in targets]
    for a in range(len(centred)):
        for b in range(a):
            ta, tb = centred[a], centred[b]
            if ta.vertices.shape == tb.vertices.shape and np.array_equal(ta.faces, tb.faces) \
                    and np.allclose(ta.vertices, tb.vertices, atol=1e-9):
                raise DesignError(f"duplicate targets: {names[a]} and {names[b]} are the same shape; give each once")
    return centred, names


def initial_rest_shape(base: TriMesh, targets, volume_scale: float = 0.8, device: str = "cpu") -> TriMesh:
    """Rest shape from the base mesh's directions: mean of volume-normalised sampled target radii,
    scaled to ``volume_scale`` x the smallest target volume."""
    from .sampling import RadialSampler

    base = base.centered()
    dirs = base.vertices / np.linalg.norm(base.vertices, axis=1, keepdims=True)
    sampler = RadialSampler(targets, device=device)
    radii = []
    for j, t in enumerate(targets):
        hits = sampler.sample(dirs * 1e-3, j)
        radii.append(np.linalg.norm(hits, axis=1) / t.volume() ** (1.0 / 3.0))
    rest = base.copy_with(dirs * np.mean(radii, axis=0)[:, None])
    rest = TriMesh(rest.vertices, rest.faces)  # validate: averaging radii keeps a star-shaped, closed membrane
    scale = (volume_scale * min(t.volume() for t in targets) / rest.volume()) ** (1.0 / 3.0)
    return rest.scaled(scale)


def _cell_faces_estimate(rest: TriMesh, radius: float) -> float:
    return max(1.0, math.pi * radius**2 / float(np.mean(rest.face_areas())))


def design(base: TriMesh, targets, actuators: int = 4, *, device: str = "cpu", target_names=None,
           settings: DesignSettings | None = None, control_settings: ControlSettings | None = None,
           material: Material | None = None, progress=None, on_round=None, recorder=None,
           **overrides) -> DesignResult:
    """Design a shape display for ``targets`` with ``actuators`` IPAMs (Algorithm 1).

    ``progress(round, n_rounds, step, max_steps, done, worlds)`` is called during control runs;
    ``on_round(i, design_i, results_i)`` after each round (e.g. to write outputs as they finish).
    ``recorder`` logs every round's control runs under ``design/round_<i>`` and the PCC by round
    (``recorder.log_design_round(round, pcc_row, target_names, design)``).
    Keyword overrides go to ``DesignSettings`` (e.g. ``cell_radius=0.016``, ``initialize=False``).
    """
    if not isinstance(base, TriMesh):
        raise DesignError(f"base must be a ws.TriMesh (e.g. ws.icosphere(3, 0.035)), got {type(base).__name__}")
    if isinstance(actuators, bool) or not isinstance(actuators, (int, np.integer)) or actuators < 1:
        raise DesignError(f"actuators must be a whole number >= 1, got {actuators!r}")
    settings = settings or DesignSettings()
    if overrides:
        settings = replace_settings(settings, overrides, "designer")
    control_settings = control_settings or ControlSettings()
    targets, names = _check_targets(targets, target_names)
    from .sampling import RadialSampler

    sampler = RadialSampler(targets, device=device)  # rejects non-star-shaped targets with the directions
    rest = initial_rest_shape(base, targets, settings.volume_scale, device) if settings.initialize else base.centered()
    per_cell = _cell_faces_estimate(rest, settings.cell_radius)
    if 2 * actuators * per_cell > rest.n_faces:
        raise DesignError(
            f"{actuators} actuators need about {2 * actuators * per_cell:.0f} faces of jamming cells "
            f"(radius {settings.cell_radius * 1e3:.1f} mm) but the membrane has {rest.n_faces}; use fewer "
            f"actuators, a smaller cell_radius or a finer base mesh")
    current = Design(rest, material)
    designs, rounds, added = [], [], []
    passive_i = [set() for _ in targets]  # per target: IPAMs left out of its control sequence
    passive_c = [set() for _ in targets]
    new_cells: list[int] = []
    pcc = np.zeros((actuators + 1, len(targets)))
    centroids_rest = rest.face_centroids()
    vol_scale = np.array([t.volume() ** (1.0 / 3.0) for t in targets])
    for i in range(actuators + 1):
        designs.append(copy_design(current))

        def ctl_progress(step, total, done, worlds, _i=i):
            if progress is not None:
                progress(_i, actuators, step, total, done, worlds)

        results = control_many(current, targets, device=device, settings=control_settings, progress=ctl_progress,
                               passive_ipams=[sorted(p) for p in passive_i], passive_cells=[sorted(p) for p in passive_c],
                               recorder=recorder, recorder_prefix=f"design/round_{i}", target_names=names)
        if i > 0 and settings.select_actuators:
            worse = [j for j, r in enumerate(results) if r.pcc < pcc[i - 1, j] - settings.max_drop]
            if worse:
                # the paper (V-C): an actuator can be held neutral for a target it does not help
                new_i, new_c = {current.n_ipams - 1}, set(new_cells)
                retry = control_many(current, [targets[j] for j in worse], device=device, settings=control_settings,
                                     passive_ipams=[sorted(passive_i[j] | new_i) for j in worse],
                                     passive_cells=[sorted(passive_c[j] | new_c) for j in worse],
                                     recorder=recorder, recorder_prefix=f"design/round_{i}_selected",
                                     target_names=[names[j] for j in worse])
                for j, r in zip(worse, retry):
                    if r.pcc > results[j].pcc:
                        results[j] = r
                        passive_i[j] |= new_i
                        passive_c[j] |= new_c
                        added[-1].setdefault("left_out_for", []).append(names[j])
        rounds.append(results)
        pcc[i] = [r.pcc for r in results]
        if recorder is not None:
            recorder.log_design_round(i, pcc[i].copy(), names, designs[-1])
        if on_round is not None:
            on_round(i, designs[-1], results)
        if i == actuators:
            break
        # scaled radial error at the achieved face centroids, per target
        errors, cents = [], []
        for j, r in enumerate(results):
            c = r.achieved.face_centroids()
            R = np.linalg.norm(sampler.sample(c, j), axis=1)
            errors.append((R - np.linalg.norm(c, axis=1)) / vol_scale[j])
            cents.append(c)
        errors = np.array(errors)  # (n_targets, F)
        face_cell = current.face_cell()
        ends = {f for ip in current.ipams for f in (ip.face_a, ip.face_b)}
        free = face_cell < 0
        free[list(ends)] = False
        if not free.any():
            raise DesignError(f"no free face left for actuator {i + 1} of {actuators}: every face is in a cell or "
                              f"an IPAM end; use fewer actuators or a smaller cell_radius")
        masked = np.where(free[None, :], np.abs(errors), -np.inf)
        j_max, f_max = np.unravel_index(int(np.argmax(masked)), masked.shape)
        e_max = errors[j_max, f_max]
        u = cents[j_max] / np.linalg.norm(cents[j_max], axis=1, keepdims=True)
        far = u @ u[f_max] <= math.cos(math.radians(settings.min_angle_deg))
        same = np.sign(errors[j_max]) == np.sign(e_max)
        cand = free & far & same
        if not cand.any():
            cand = free & far  # no same-sign face left: the smallest opposite-sign error hurts least
            if not cand.any():
                raise DesignError(f"no free face at least {settings.min_angle_deg} degrees from face {f_max} for "
                                  f"actuator {i + 1}; use fewer actuators or a smaller cell_radius")
        score = np.where(cand, errors[j_max] * np.sign(e_max), -np.inf)
        f_other = int(np.argmax(score))
        current.add_ipam(int(f_max), f_other, stiffness=settings.ipam_stiffness, area=settings.ipam_area,
                         pressure_limits=settings.ipam_pressure_limits, damping=settings.ipam_damping)
        new_cells = []
        for end in (int(f_max), f_other):
            face_cell = current.face_cell()
            near = np.flatnonzero((np.linalg.norm(centroids_rest - centroids_rest[end], axis=1) < settings.cell_radius)
                                  & (face_cell < 0))
            if near.size:
                new_cells.append(current.add_cell(near))
        added.append(dict(round=i, target=int(j_max), face_a=int(f_max), face_b=f_other, error=float(e_max),
                          error_b=float(errors[j_max, f_other])))
    return DesignResult(design=current, designs=designs, rounds=rounds, pcc_by_round=pcc, target_names=names,
                        targets=targets, added=added, settings=settings, control_settings=control_settings,
                        passive_ipams=[sorted(p) for p in passive_i], passive_cells=[sorted(p) for p in passive_c])
