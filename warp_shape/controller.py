"""Drive a design to target shapes (paper section IV-B, SPEC section 6).

Every control period (several simulation steps) the controller samples each target radially at the
membrane's vertices, then updates
- the chamber air by eq. (11): dn = (V_t - V) p_abs / (R T), V_t the volume of the sampled target;
- each IPAM by eq. (12): dP = (k / A) (L_t - L), L_t the distance between the centroids of the IPAM's
  end faces on the sampled target;
- each jamming cell by eqs. (13)-(15): curvature kappa = r_end - mean r over the cell's faces (radius
  of a face = |centroid|); a cell jams the first control step its curvature moves away from its
  target (it is not between the previous value and the target), once, never released.
Phase 1 (initial inflation) actuates only the air until the volume is in its deadband. Increments
are rate limited; the run stops when volume and every IPAM length are in their deadbands, or at the
step limit (``converged`` False, with the reason). An IPAM pinned at a pressure limit while its
target asks for more counts as settled: it cannot do better. Eqs. (11)-(12) are deadbeat laws that
assume the membrane settles within a control period; where it does not (coarse, lightly damped
membranes), an error that flips sign without halving halves that world's (or IPAM's) gain, down
to ``min_gain`` (``gain_backoff``; not in the paper).

Several targets of one design run as one batch of simulated worlds (one launch per kernel for all).

History columns (one row per control step: the state measured at that step, before its update;
``phase`` is the control law applied at that step; ``{i}`` IPAM index,
``{j}`` cell index):
  step, time (s), phase (1 inflation / 2 shape control), air_mol, pressure_pa (gauge), volume_m3,
  target_volume_m3, ipam{i}_pressure_pa, ipam{i}_length_m, ipam{i}_target_length_m, ipam{i}_force_n
  (axial, + = tension), ipam{i}_strain ((L - L0) / L0), cell{j}_kappa_m, cell{j}_kappa_target_m,
  cell{j}_jammed (0/1), pcc, mare_m, mpre_pct.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from .design import Design
from .errors import DesignError
from .material import GAS_CONSTANT
from .mesh import TriMesh
from .model import volumes_np
from .settings import SimulationSettings, replace_settings
from .sampling import pcc

__all__ = ["ControlSettings", "ControlResult", "control", "control_many", "cell_anchor_faces"]


@dataclass(frozen=True)
class ControlSettings:
    """Controller parameters (SI). Defaults were chosen by measurement on the Fig. 6 problem and the
    oval/heart design problem (see docs/controller.md)."""

    control_period: int = 10  # simulation steps (of simulation.dt) per control step
    max_steps: int = 300  # control-step limit
    volume_deadband: float = 0.005  # |V - V_t| / V_t
    length_deadband: float = 1e-3  # |L_t - L|, m
    air_rate: float = 0.04  # max |dn| per control step, as a fraction of the rest air amount
    pressure_rate: float = 40e3  # max |dP| per control step, Pa
    air_gain: float = 1.0  # multiplies eq. (11)
    pressure_gain: float = 1.0  # multiplies eq. (12)
    gain_backoff: float = 0.5  # an error that flips sign without halving scales that actuator's gain by this
    min_gain: float = 0.05  # floor of the backed-off gains, relative to air_gain / pressure_gain
    jamming: bool = True  # False: never jam (for path-dependence studies)
    curvature_tolerance: float = 1e-6  # m; a move away from the target smaller than this is noise
    max_stretch: float = 4.0  # mean edge stretch beyond which the target is deemed unreachable
    simulation: SimulationSettings = field(default_factory=SimulationSettings)  # integrator, dt, precision, ...

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise DesignError(f"ControlSettings.{f.name} must be finite, got {v}")
        if self.control_period < 1 or self.max_steps < 1:
            raise DesignError("ControlSettings needs control_period >= 1 and max_steps >= 1")
        if not isinstance(self.simulation, SimulationSettings):
            raise DesignError(f"ControlSettings.simulation must be a SimulationSettings (warp_shape.settings), "
                              f"got {type(self.simulation).__name__}")
        for name in ("volume_deadband", "length_deadband", "air_rate", "pressure_rate", "air_gain", "pressure_gain",
                     "gain_backoff", "min_gain"):
            if getattr(self, name) <= 0:
                raise DesignError(f"ControlSettings.{name} must be > 0, got {getattr(self, name)}")

    def replace(self, **changes) -> "ControlSettings":
        """A copy with some settings changed; unknown names raise ``DesignError``."""
        return replace_settings(self, changes, "controller")


@dataclass
class ControlResult:
    """Outcome of driving one design to one target."""

    achieved: TriMesh  # membrane at the end of the control sequence
    sampled_target: TriMesh  # the target sampled radially through the achieved vertices
    pcc: float
    mare: float  # m
    mpre: float  # %
    volume_error: float  # (V - V_t) / V_t
    ipam_forces: np.ndarray  # (n_ipam,) final axial forces, N (+ = tension)
    ipam_pressures: np.ndarray  # (n_ipam,) final gauge pressures, Pa
    air_moles: float
    jammed: np.ndarray  # (n_cell,) bool
    jam_steps: np.ndarray  # (n_cell,) control step at which each cell jammed, -1 if never
    converged: bool
    reason: str
    control_steps: int
    history: dict = field(repr=False)  # column name -> (n_steps,) array, see module docstring
    settings: ControlSettings = field(repr=False, default_factory=ControlSettings)
    frames: np.ndarray | None = field(repr=False, default=None)  # (n_steps, V, 3) float32 membrane per control step
    design: Design | None = field(repr=False, default=None)
    target: TriMesh | None = field(repr=False, default=None)
    passive_ipams: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # left out of this run
    passive_cells: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def actuator_summary(self) -> list[dict]:
        """Per IPAM what a builder needs to size it (section IV-C): peak push and pull force (N),
        peak |strain|, and the pressure range used (Pa)."""
        out = []
        for i in range(len(self.ipam_forces)):
            f = self.history[f"ipam{i}_force_n"]
            s = self.history[f"ipam{i}_strain"]
            p = self.history[f"ipam{i}_pressure_pa"]
            out.append(dict(ipam=i, peak_push_n=float(max(0.0, -f.min())), peak_pull_n=float(max(0.0, f.max())),
                            peak_strain=float(np.abs(s).max()), pressure_min_pa=float(p.min()),
                            pressure_max_pa=float(p.max())))
        return out

    def summary(self) -> dict:
        """Fit, final actuator state, convergence and settings as a JSON-ready dict (SI units)."""
        return dict(pcc=self.pcc, mare_m=self.mare, mpre_pct=self.mpre, volume_error=self.volume_error,
                    converged=self.converged, reason=self.reason, control_steps=self.control_steps,
                    air_moles=self.air_moles, ipam_forces_n=self.ipam_forces.tolist(),
                    ipam_pressures_pa=self.ipam_pressures.tolist(), jammed=self.jammed.tolist(),
                    jam_steps=self.jam_steps.tolist(), actuators=self.actuator_summary,
                    passive_ipams=self.passive_ipams.tolist(), passive_cells=self.passive_cells.tolist(),
                    settings=asdict(self.settings))


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


def _passive_mask(spec, W: int, n: int, what: str) -> np.ndarray:
    """(W, n) bool from indices shared by all worlds, or one index list per world."""
    mask = np.zeros((W, n), dtype=bool)
    spec = list(spec)
    per_world = len(spec) == W and all(isinstance(s, (list, tuple, np.ndarray, set)) for s in spec)
    try:
        for w in range(W):
            idx = list(spec[w]) if per_world else spec
            mask[w, np.asarray(idx, dtype=np.int64)] = True
    except (IndexError, ValueError, TypeError):
        raise DesignError(f"{what} must be indices in 0..{n - 1} (or one list per target), got {spec!r}") from None
    return mask


def control_many(design: Design, targets, *, device: str = "cpu", settings: ControlSettings | None = None,
                 recorder=None, progress=None, passive_ipams=(), passive_cells=(), target_names=None,
                 recorder_prefix: str = "control", **overrides) -> list[ControlResult]:
    """Drive ``design`` to every target at once (one simulated world per target).

    ``passive_ipams`` / ``passive_cells``: actuators left out of this control sequence (indices for
    every target, or one list per target). A passive
    IPAM's pressure tracks its current length (natural length = length, so it exerts ~no force);
    a passive cell never jams. The paper (section V-C) notes an actuator can be neutralised this way.
    """
    from .sampling import RadialSampler
    from .simulator import Simulator

    if not isinstance(design, Design):
        raise DesignError(f"control needs a ws.Design, got {type(design).__name__}")
    if isinstance(targets, TriMesh):
        targets = [targets]
    targets = list(targets)
    if not targets:
        raise DesignError("control needs at least one target")
    for t in targets:
        if not isinstance(t, TriMesh):
            raise DesignError(f"targets must be ws.TriMesh (e.g. ws.target('cube')), got {type(t).__name__}")
    settings = settings or ControlSettings()
    if overrides:
        settings = settings.replace(**overrides)
    targets = [t.centered() for t in targets]
    W = len(targets)
    sampler = RadialSampler(targets, device=device)  # checks star-shape; raises ShapeError naming directions
    ss = settings.simulation
    sim = Simulator(design, device=device, integrator=ss.integrator, dt=ss.dt, precision=ss.precision,
                    bending=ss.bending, substeps=ss.substeps, worlds=W, launch_mode=ss.launch_mode,
                    reestimate_every=ss.reestimate_every)
    m = sim.model
    h = m.host
    faces = h.faces
    n_ipam, n_cell = design.n_ipams, design.n_cells
    rt = GAS_CONSTANT * m.temperature
    n_rest = float(np.atleast_1d(sim.air_moles)[0])
    k_ipam = h.ipam_stiffness
    a_over_k = h.ipam_area_over_k
    free_len = h.ipam_free_length
    limits = h.ipam_limits
    ipam_faces = h.ipam_faces
    anchors = cell_anchor_faces(design)
    passive_i = _passive_mask(passive_ipams, W, n_ipam, "passive_ipams")  # (W, n_ipam)
    passive_c = _passive_mask(passive_cells, W, n_cell, "passive_cells")  # (W, n_cell)
    cell_faces = [c.faces for c in design.cells]
    rest_edge = h.rest_length
    hinges = h.hinges

    air = np.full(W, n_rest)
    gain_air = np.full(W, settings.air_gain)  # backed off per world when the volume oscillates
    gain_p = np.full((W, n_ipam), settings.pressure_gain)  # per world and IPAM
    err_v_prev = np.zeros(W)
    err_l_prev = np.zeros((W, n_ipam))
    pressures = np.zeros((W, n_ipam))
    phase = np.ones(W, dtype=np.int64)
    done = np.zeros(W, dtype=bool)
    reason = ["step limit reached"] * W
    snapshot = [None] * W
    kappa_prev = None
    jam_steps = np.full((W, n_cell), -1, dtype=np.int64)
    rows: list[list[dict]] = [[] for _ in range(W)]
    frames: list[list[np.ndarray]] = [[] for _ in range(W)]
    w_idx = np.arange(W)
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(W)]
    if recorder is not None:
        recorder.begin_run(design=design, targets=targets, target_names=names, prefix=recorder_prefix,
                           settings=settings)

    for step in range(settings.max_steps + 1):
        x = np.asarray(sim.positions, dtype=np.float64).reshape(W, -1, 3)
        sampled = sampler.sample_worlds(x, w_idx)
        vol = volumes_np(x, faces)
        vol_t = volumes_np(sampled, faces)
        p_abs = air * rt / vol
        cen = x[:, faces].mean(axis=2)  # (W, F, 3)
        cen_t = sampled[:, faces].mean(axis=2)
        r_f, r_ft = np.linalg.norm(cen, axis=2), np.linalg.norm(cen_t, axis=2)
        if n_ipam:
            L = np.linalg.norm(cen[:, ipam_faces[:, 1]] - cen[:, ipam_faces[:, 0]], axis=2)
            L_t = np.linalg.norm(cen_t[:, ipam_faces[:, 1]] - cen_t[:, ipam_faces[:, 0]], axis=2)
            force = k_ipam * (L - (free_len + a_over_k * pressures))
        else:
            L = L_t = force = np.zeros((W, 0))
        kappa = np.stack([r_f[:, anchors[j]] - r_f[:, cell_faces[j]].mean(axis=1) for j in range(n_cell)], 1) \
            if n_cell else np.zeros((W, 0))
        kappa_t = np.stack([r_ft[:, anchors[j]] - r_ft[:, cell_faces[j]].mean(axis=1) for j in range(n_cell)], 1) \
            if n_cell else np.zeros((W, 0))
        r_v, r_vt = np.linalg.norm(x, axis=2), np.linalg.norm(sampled, axis=2)
        jammed_now = np.asarray(sim.jammed).reshape(W, n_cell)
        vol_ok = np.abs(vol - vol_t) / vol_t < settings.volume_deadband
        phase = np.where((phase == 1) & vol_ok & ~done, 2, phase)  # inflation done: shape control starts
        for w in range(W):
            if done[w]:
                continue
            row = dict(step=step, time=sim.time, phase=int(phase[w]), air_mol=air[w],
                       pressure_pa=p_abs[w] - m.atmospheric_pressure, volume_m3=vol[w], target_volume_m3=vol_t[w])
            for i in range(n_ipam):
                row[f"ipam{i}_pressure_pa"] = pressures[w, i]
                row[f"ipam{i}_length_m"] = L[w, i]
                row[f"ipam{i}_target_length_m"] = L_t[w, i]
                row[f"ipam{i}_force_n"] = force[w, i]
                row[f"ipam{i}_strain"] = (L[w, i] - free_len[i]) / free_len[i]
            for j in range(n_cell):
                row[f"cell{j}_kappa_m"] = kappa[w, j]
                row[f"cell{j}_kappa_target_m"] = kappa_t[w, j]
                row[f"cell{j}_jammed"] = int(jammed_now[w, j])
            row["pcc"] = pcc(r_v[w], r_vt[w])
            row["mare_m"] = float(np.mean(np.abs(r_v[w] - r_vt[w])))
            row["mpre_pct"] = float(100.0 * np.mean(np.abs(r_v[w] - r_vt[w]) / r_vt[w]))
            rows[w].append(row)
            frames[w].append(x[w].astype(np.float32))

        if recorder is not None:
            recorder.log_control_step(step=step, time=sim.time, positions=x, sampled=sampled, rows=rows, done=done)

        # ---- convergence and guards
        if n_ipam:
            # an IPAM pinned at a pressure limit and still asked to go further cannot do better
            want = L_t - L
            pinned = ((pressures >= limits[:, 1]) & (want > 0)) | ((pressures <= limits[:, 0]) & (want < 0))
            len_ok = np.all((np.abs(want) < settings.length_deadband) | pinned | passive_i, axis=1)
        else:
            len_ok = np.ones(W, bool)
        stretch = np.linalg.norm(x[:, hinges[:, 1]] - x[:, hinges[:, 0]], axis=2) / rest_edge
        for w in range(W):
            if done[w]:
                continue
            if phase[w] == 2 and vol_ok[w] and len_ok[w]:
                done[w], reason[w] = True, "converged: volume and IPAM lengths within their deadbands (or IPAMs at a pressure limit)"
            elif stretch[w].mean() > settings.max_stretch:
                done[w], reason[w] = True, (f"target unreachable: mean membrane stretch {stretch[w].mean():.2f} "
                                            f"exceeds max_stretch {settings.max_stretch}")
            elif step == settings.max_steps:
                done[w] = True
            if done[w]:
                snapshot[w] = (x[w].copy(), sampled[w].copy(), force[w].copy(), pressures[w].copy(), air[w],
                               jammed_now[w].copy(), step, vol[w], vol_t[w])
        if progress is not None:
            progress(step, settings.max_steps, int(done.sum()), W)
        if done.all():
            break

        # ---- control updates (worlds already done keep their controls)
        active = ~done
        # gain back-off: eqs. (11)-(12) are deadbeat laws that assume the membrane settles within one
        # control period; when an error flips sign without halving, the loop overshoots, so halve it
        err_v = (vol_t - vol) / vol_t
        flip = (err_v * err_v_prev < 0) & (np.abs(err_v) > 0.5 * np.abs(err_v_prev)) \
            & (np.abs(err_v) > settings.volume_deadband)
        gain_air = np.where(flip & active, np.maximum(gain_air * settings.gain_backoff,
                                                      settings.min_gain * settings.air_gain), gain_air)
        err_v_prev = err_v
        if n_ipam:
            err_l = L_t - L
            flip_l = (err_l * err_l_prev < 0) & (np.abs(err_l) > 0.5 * np.abs(err_l_prev)) \
                & (np.abs(err_l) > settings.length_deadband) & (phase[:, None] == 2)
            gain_p = np.where(flip_l & active[:, None], np.maximum(gain_p * settings.gain_backoff,
                                                                   settings.min_gain * settings.pressure_gain), gain_p)
            err_l_prev = err_l
        dn = gain_air * (vol_t - vol) * p_abs / rt
        lim = settings.air_rate * n_rest
        air = np.where(active, np.maximum(air + np.clip(dn, -lim, lim), 0.0), air)
        shaping = active & (phase == 2)
        if n_ipam:
            dP = gain_p * (L_t - L) / a_over_k
            dP = np.clip(dP, -settings.pressure_rate, settings.pressure_rate)
            newP = np.clip(pressures + dP, limits[:, 0], limits[:, 1])
            pressures = np.where(shaping[:, None], newP, pressures)
            if passive_i.any():  # natural length follows the length: no force, in every phase
                neutral = np.clip((L - free_len) / a_over_k, limits[:, 0], limits[:, 1])
                pressures = np.where(active[:, None] & passive_i, neutral, pressures)
        if n_cell and settings.jamming and kappa_prev is not None:
            tol = settings.curvature_tolerance
            lo = np.minimum(kappa_t, kappa_prev) - tol
            hi = np.maximum(kappa_t, kappa_prev) + tol
            away = (kappa < lo) | (kappa > hi)
            for w, j in zip(*np.nonzero(away & shaping[:, None] & ~jammed_now & ~passive_c)):
                sim.jam(int(j), world=int(w))
                jam_steps[w, j] = step
        kappa_prev = kappa
        sim.air_moles = air
        if n_ipam:
            sim.ipam_pressures = pressures
        sim.step(settings.control_period)

    results = []
    for w in range(W):
        xw, sw, fw, pw, aw, jw, steps, vw, vtw = snapshot[w]
        hist = {k: np.array([r[k] for r in rows[w]]) for k in rows[w][0]}
        r, R = np.linalg.norm(xw, axis=1), np.linalg.norm(sw, axis=1)
        results.append(ControlResult(
            achieved=design.rest.copy_with(xw), sampled_target=design.rest.copy_with(sw),
            pcc=pcc(r, R), mare=float(np.mean(np.abs(r - R))), mpre=float(100 * np.mean(np.abs(r - R) / R)),
            volume_error=float((vw - vtw) / vtw), ipam_forces=fw, ipam_pressures=pw, air_moles=float(aw),
            jammed=jw.astype(bool), jam_steps=jam_steps[w].copy(), converged=reason[w].startswith("converged"),
            reason=reason[w], control_steps=int(steps), history=hist, settings=settings,
            frames=np.stack(frames[w]), design=design, target=targets[w],
            passive_ipams=np.flatnonzero(passive_i[w]), passive_cells=np.flatnonzero(passive_c[w])))
    if recorder is not None:
        recorder.end_run(results)
    return results


def control(design: Design, target: TriMesh, *, device: str = "cpu", settings: ControlSettings | None = None,
            recorder=None, progress=None, passive_ipams=(), passive_cells=(), target_name: str = "target",
            **overrides) -> ControlResult:
    """Drive ``design`` to one ``target`` (centred on its volume centroid first)."""
    return control_many(design, [target], device=device, settings=settings, recorder=recorder, progress=progress,
                        passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=[target_name],
                        **overrides)[0]
