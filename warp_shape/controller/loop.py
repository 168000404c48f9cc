"""The control loop: set up the worlds, then observe -> law -> apply -> record -> stop, then the results.

``control_many`` drives one design to several targets at once (one simulated world per target);
``control`` to one target.
"""

from __future__ import annotations

import numpy as np

from ..design import Design
from ..errors import DesignError
from ..mesh import TriMesh
from ..sampling import RadialSampler, pcc
from ..targets import centred_targets
from ..settings import SimulationSettings
from .history import History
from .laws import LAWS, Controls, PaperLaw
from .observe import DeviceConstants, Observation, Observer
from .result import ControlResult
from .settings import ControlSettings

__all__ = ["control", "control_many", "CONVERGED"]

CONVERGED = "converged: volume and IPAM lengths within their deadbands (or IPAMs at a pressure limit)"


def _checked_targets(design, targets) -> list[TriMesh]:
    """The targets as a list of centred meshes; clear errors for a wrong design or target."""
    if not isinstance(design, Design):
        raise DesignError(f"control needs a ws.Design, got {type(design).__name__}")
    return centred_targets(targets, "control")


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


def _simulator(design: Design, s: SimulationSettings, device: str, worlds: int):
    from ..simulator import Simulator

    return Simulator(design, device=device, integrator=s.integrator, dt=s.dt, precision=s.precision,
                     bending=s.bending, substeps=s.substeps, worlds=worlds, launch_mode=s.launch_mode,
                     reestimate_every=s.reestimate_every)


class _StopRule:
    """Per world: done once settled in phase 2 (volume and IPAM lengths in their deadbands, an IPAM
    pinned at a pressure limit counting as settled), stretched beyond ``max_stretch``, or at the step
    limit; keeps the observation and controls at which each world finished."""

    def __init__(self, settings: ControlSettings, dev: DeviceConstants, passive_ipams: np.ndarray):
        W = passive_ipams.shape[0]
        self.settings, self.dev, self.passive_ipams = settings, dev, passive_ipams
        self.done = np.zeros(W, dtype=bool)
        self.reason = ["step limit reached"] * W
        self.final: list = [None] * W  # (observation, controls) at the end of each world's run

    def _lengths_settled(self, obs: Observation, pressures: np.ndarray) -> np.ndarray:
        if not self.dev.n_ipam:
            return np.ones(len(self.done), bool)
        # an IPAM pinned at a pressure limit and still asked to go further cannot do better
        lim = self.dev.ipam_limits
        want = obs.ipam_target_lengths - obs.ipam_lengths
        pinned = ((pressures >= lim[:, 1]) & (want > 0)) | ((pressures <= lim[:, 0]) & (want < 0))
        return np.all((np.abs(want) < self.settings.length_deadband) | pinned | self.passive_ipams, axis=1)

    def check(self, obs: Observation, phase: np.ndarray, controls: Controls) -> None:
        s = self.settings
        vol_ok = obs.volume_within(s.volume_deadband)
        len_ok = self._lengths_settled(obs, controls.pressures)
        for w in np.flatnonzero(~self.done):
            if phase[w] == 2 and vol_ok[w] and len_ok[w]:
                self.done[w], self.reason[w] = True, CONVERGED
            elif obs.mean_stretch[w] > s.max_stretch:
                self.done[w], self.reason[w] = True, (f"target unreachable: mean membrane stretch "
                                                      f"{obs.mean_stretch[w]:.2f} exceeds max_stretch {s.max_stretch}")
            elif obs.step == s.max_steps:
                self.done[w] = True
            if self.done[w]:
                self.final[w] = (obs, controls)


def _run(sim, observer: Observer, law: PaperLaw, stop: _StopRule, history: History, *, progress=None,
         recorder=None) -> np.ndarray:
    """Observe, record, stop, then apply the law's controls, every control period until every world is
    done; returns (W, n_cell) the control step at which each cell jammed (-1: never)."""
    dev, s = observer.dev, stop.settings
    W = len(stop.done)
    controls = Controls(air=np.full(W, dev.rest_air), pressures=np.zeros((W, dev.n_ipam)))
    jam_steps = np.full((W, dev.n_cell), -1, dtype=np.int64)
    for step in range(s.max_steps + 1):
        obs = observer.observe(sim, step, controls.air, controls.pressures)
        phase = law.update_phase(obs, stop.done)
        history.record(obs, phase, controls, stop.done)
        if recorder is not None:
            recorder.log_control_step(step=step, time=obs.time, positions=obs.positions, sampled=obs.sampled,
                                      rows=history.rows, done=stop.done)
        stop.check(obs, phase, controls)
        if progress is not None:
            progress(step, s.max_steps, int(stop.done.sum()), W)
        if stop.done.all():
            break
        out = law.step(obs, controls, ~stop.done)  # worlds already done keep their controls
        for w, j in out.jam:
            sim.jam(j, world=w)
            jam_steps[w, j] = step
        controls = out.controls
        sim.air_moles = controls.air
        if dev.n_ipam:
            sim.ipam_pressures = controls.pressures
        sim.step(s.control_period)
    return jam_steps


def _result(w: int, stop: _StopRule, history: History, jam_steps: np.ndarray, design: Design, target: TriMesh,
            passive_ipams: np.ndarray, passive_cells: np.ndarray) -> ControlResult:
    obs, controls = stop.final[w]
    x, sampled = obs.positions[w].copy(), obs.sampled[w].copy()
    r, R = np.linalg.norm(x, axis=1), np.linalg.norm(sampled, axis=1)
    vol, vol_t = obs.volume[w], obs.target_volume[w]
    return ControlResult(
        achieved=design.rest.copy_with(x), sampled_target=design.rest.copy_with(sampled),
        pcc=pcc(r, R), mare=float(np.mean(np.abs(r - R))), mpre=float(100 * np.mean(np.abs(r - R) / R)),
        volume_error=float((vol - vol_t) / vol_t), ipam_forces=obs.ipam_forces[w].copy(),
        ipam_pressures=controls.pressures[w].copy(), air_moles=float(controls.air[w]),
        jammed=obs.jammed[w].copy().astype(bool), jam_steps=jam_steps[w].copy(),
        converged=stop.reason[w].startswith("converged"), reason=stop.reason[w], control_steps=int(obs.step),
        history=history.columns(w), settings=stop.settings, frames=history.frame_stack(w), design=design,
        target=target, passive_ipams=np.flatnonzero(passive_ipams[w]), passive_cells=np.flatnonzero(passive_cells[w]))


def control_many(design: Design, targets, *, device: str = "cpu", settings: ControlSettings | None = None,
                 recorder=None, progress=None, passive_ipams=(), passive_cells=(), target_names=None,
                 recorder_prefix: str = "control", method: str | None = None, **overrides) -> list[ControlResult]:
    """Drive ``design`` to every target at once (one simulated world per target, each centred on its
    volume centroid first) with ``method`` (default ``settings.method``): ``"inverse"``, the paper's
    law as warm start then model-based control (``controller.inverse``), or ``"paper"``, the paper's law.

    ``passive_ipams`` / ``passive_cells``: actuators left out of this control sequence (indices for
    every target, or one list per target). A passive IPAM's pressure tracks its current length
    (natural length = length, so it exerts ~no force); a passive cell never jams. The paper (section
    V-C) notes an actuator can be neutralised this way. ``progress(step, max_steps, done, worlds)``
    is called every control step; ``recorder`` logs the run. Keyword overrides go to ``settings``.
    """
    targets = _checked_targets(design, targets)
    settings = settings or ControlSettings()
    if method is not None:
        overrides["method"] = method
    if overrides:
        settings = settings.replace(**overrides)
    if settings.method == "inverse":
        from .inverse import control_inverse

        return control_inverse(design, targets, device=device, settings=settings, progress=progress, recorder=recorder,
                               recorder_prefix=recorder_prefix, passive_ipams=passive_ipams,
                               passive_cells=passive_cells, target_names=target_names)
    W = len(targets)
    sampler = RadialSampler(targets, device=device)  # checks star-shape; raises ShapeError naming directions
    sim = _simulator(design, settings.simulation, device, W)
    dev = DeviceConstants.of(sim, design)
    passive_i = _passive_mask(passive_ipams, W, dev.n_ipam, "passive_ipams")  # (W, n_ipam)
    passive_c = _passive_mask(passive_cells, W, dev.n_cell, "passive_cells")  # (W, n_cell)
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(W)]
    if recorder is not None:
        recorder.begin_run(design=design, targets=targets, target_names=names, prefix=recorder_prefix,
                           settings=settings)
    stop, history = _StopRule(settings, dev, passive_i), History(W, dev)
    law = LAWS["paper"](settings, dev, passive_i, passive_c)
    jam_steps = _run(sim, Observer(dev, sampler, W), law, stop, history, progress=progress, recorder=recorder)
    results = [_result(w, stop, history, jam_steps, design, targets[w], passive_i, passive_c) for w in range(W)]
    if recorder is not None:
        recorder.end_run(results)
    return results


def control(design: Design, target: TriMesh, *, device: str = "cpu", settings: ControlSettings | None = None,
            recorder=None, progress=None, passive_ipams=(), passive_cells=(), target_name: str = "target",
            method: str | None = None, **overrides) -> ControlResult:
    """Drive ``design`` to one ``target`` (centred on its volume centroid first) with ``method``
    (``"inverse"`` or ``"paper"``, default ``settings.method``)."""
    return control_many(design, [target], device=device, settings=settings, recorder=recorder, progress=progress,
                        passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=[target_name],
                        method=method, **overrides)[0]
