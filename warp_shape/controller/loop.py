"""The law loop: set up the worlds, then observe -> law -> apply -> record -> stop, then the results.

``run_law`` drives one design to several targets at once (one simulated world per target) with one
control law; ``controller.methods`` builds the control methods on it.
"""

from __future__ import annotations

import numpy as np

from ..display import Design
from ..errors import DesignError
from ..mesh import TriMesh
from ..model import HostModel
from ..simulation_settings import SimulationSettings
from .history import History
from .laws import Controls, PaperLaw, hold_neutral
from .observe import Observation, Observer
from .problem import as_problem
from .result import ControlResult
from .control_settings import ControlSettings
from .worlds import mask_passive

__all__ = ["run_law", "SETTLE_PHASE"]


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

    return Simulator(design, device=device, settings=s, worlds=worlds)


RUNNING, SETTLING, DONE = 0, 1, 2
SETTLE_PHASE = 3  # the history's phase of a step at which the controls are held for the membrane to settle


class _Ending:
    """Per world: running (the law acts), settling (controls held until the membrane is at rest) or done.

    A running world starts settling when it meets its deadbands in phase 2 (volume and every IPAM
    length; an IPAM pinned at a pressure limit while its target asks for more counts as met, since
    it cannot move further), when the mean edge stretch passes ``max_stretch``, or after
    ``max_steps`` steps of the law. It settles until its largest vertex speed is below
    ``settle_speed`` (at rest) or for ``max_settle_steps`` control steps. A world that held for its
    deadbands and left them while settling resumes control (within the step limit); otherwise it is
    done, and the observation at which it finished is what its result reports."""

    def __init__(self, settings: ControlSettings, host: HostModel, passive_ipams: np.ndarray):
        W = passive_ipams.shape[0]
        self.settings, self.host, self.passive_ipams = settings, host, passive_ipams
        self.state = np.full(W, RUNNING)
        self.cause = [""] * W  # why the world held: "deadbands", "stretch" or "step limit"
        self.stretch_note = [""] * W
        self.settle_start = np.zeros(W, dtype=np.int64)
        self.law_steps = np.zeros(W, dtype=np.int64)  # control steps at which the law acted
        self.settled = np.zeros(W, dtype=bool)
        self.final_met = np.zeros(W, dtype=bool)  # deadbands met at the final observation
        self.final: list = [None] * W  # (observation, controls) at the end of each world's run

    @property
    def running(self) -> np.ndarray:
        return self.state == RUNNING

    @property
    def done(self) -> np.ndarray:
        return self.state == DONE

    def pinned(self, obs: Observation, controls: Controls) -> np.ndarray:
        """(W, n_ipam) bool: active IPAMs at a pressure limit whose target length asks, beyond the
        length deadband, for more in that direction."""
        lim = self.host.ipam_limits
        p = controls.pressures
        want = obs.ipam_target_lengths - obs.ipam_lengths
        far = np.abs(want) >= self.settings.length_deadband
        return far & ~self.passive_ipams & (((p >= lim[:, 1]) & (want > 0)) | ((p <= lim[:, 0]) & (want < 0)))

    def deadbands_met(self, obs: Observation, controls: Controls) -> np.ndarray:
        """(W,) bool: volume and every IPAM length within their deadbands (pinned or passive IPAMs aside)."""
        vol_ok = obs.volume_within(self.settings.volume_deadband)
        if not self.host.n_ipams:
            return vol_ok
        near = np.abs(obs.ipam_target_lengths - obs.ipam_lengths) < self.settings.length_deadband
        return vol_ok & np.all(near | self.pinned(obs, controls) | self.passive_ipams, axis=1)

    def update(self, obs: Observation, phase: np.ndarray, controls: Controls) -> None:
        """Move every world on by this observation (see the class docstring)."""
        s = self.settings
        met = self.deadbands_met(obs, controls) & (phase == 2)
        for w in np.flatnonzero(self.state == RUNNING):
            cause = ("deadbands" if met[w] else "stretch" if obs.mean_stretch[w] > s.max_stretch
                     else "step limit" if self.law_steps[w] >= s.max_steps else "")
            if cause:
                self.state[w], self.cause[w], self.settle_start[w] = SETTLING, cause, obs.step
                if cause == "stretch":
                    self.stretch_note[w] = (f"target unreachable: mean membrane stretch {obs.mean_stretch[w]:.2f} "
                                            f"exceeds max_stretch {s.max_stretch:g}")
        for w in np.flatnonzero(self.state == SETTLING):
            at_rest = obs.max_speed[w] < s.settle_speed
            if at_rest and self.cause[w] == "deadbands" and not met[w]:
                if self.law_steps[w] < s.max_steps:
                    self.state[w] = RUNNING  # left the deadbands while settling: control on
                    continue
                self.cause[w] = "step limit"
            if at_rest or obs.step - self.settle_start[w] >= s.max_settle_steps:
                self.state[w], self.settled[w], self.final[w] = DONE, at_rest, (obs, controls)
                self.final_met[w] = met[w]

    def saturated(self, w: int) -> list[str]:
        """World ``w``'s actuators pinned at a limit at its final observation while their target asks for
        more, e.g. "ipam 3 at P_max 300 kPa"."""
        obs, controls = self.final[w]
        out = []
        if self.host.n_ipams:
            lim = self.host.ipam_limits
            for i in np.flatnonzero(self.pinned(obs, controls)[w]):
                top = controls.pressures[w, i] >= lim[i, 1]
                out.append(f"ipam {i} at P_{'max' if top else 'min'} {lim[i, 1 if top else 0] / 1e3:g} kPa")
        if controls.air[w] <= 0.0 and obs.volume[w] > obs.target_volume[w] * (1 + self.settings.volume_deadband):
            out.append("air at 0 mol")
        return out

    def reason(self, w: int, saturated: list[str]) -> str:
        """Why world ``w`` ended, whether it is at rest, and which limit stopped it."""
        s, obs = self.settings, self.final[w][0]
        speed = f"largest vertex speed {obs.max_speed[w] * 1e3:.2g} mm/s"
        rest = (f"at rest ({speed} < {s.settle_speed * 1e3:g} mm/s)" if self.settled[w] else
                f"not at rest: {speed} after holding the controls {obs.step - self.settle_start[w]} control steps "
                f"(max_settle_steps {s.max_settle_steps})")
        limits = ", ".join(saturated)
        if self.cause[w] == "deadbands" and not self.final_met[w]:
            head = "the deadbands were met, then left while the controls were held"
        elif self.cause[w] == "deadbands" and not saturated:
            head = ("converged" if self.settled[w] else "within the deadbands") \
                + ": volume and every IPAM length within their deadbands"
        elif self.cause[w] == "deadbands":
            ask = "their targets ask" if len(saturated) > 1 else "its target asks"
            head = (f"stopped by a limit: {limits} ({ask} for more); the volume and the other IPAM lengths within "
                    f"their deadbands")
        elif self.cause[w] == "stretch":
            head = self.stretch_note[w]
        else:
            head = f"step limit reached ({s.max_steps} control steps)" + (f"; at a limit: {limits}" if limits else "")
        return f"{head}; {rest}"


def _apply(sim, observer: Observer, law, ending: _Ending, obs: Observation, controls: Controls,
           jam_steps: np.ndarray) -> Controls:
    """The law's step for the running worlds (the others hold their controls), applied to ``sim``."""
    active = ending.running
    if active.any():
        out = law.step(obs, controls, active)
        for w, j in out.jam:
            sim.jam(j, world=w)
            jam_steps[w, j] = obs.step
        controls = out.controls
        ending.law_steps += active
    sim.air_moles = controls.air
    if observer.host.n_ipams:
        sim.ipam_pressures = controls.pressures
    hold_neutral(sim, law, observer.host, obs, active)
    return controls


def _run(sim, observer: Observer, law: PaperLaw, ending: _Ending, history: History, *, progress=None,
         recorder=None) -> np.ndarray:
    """Observe, move on, record, then apply the law's controls, every control period until every world
    is done; returns (W, n_cell) the control step at which each cell jammed (-1: never)."""
    host, s = observer.host, ending.settings
    W = len(ending.state)
    controls = Controls(air=np.full(W, host.rest_air), pressures=np.zeros((W, host.n_ipams)))
    jam_steps = np.full((W, host.n_cells), -1, dtype=np.int64)
    step = 0
    while True:
        obs = observer.observe(sim, step, controls.air, controls.pressures)
        was_done = ending.done.copy()
        phase = law.update_phase(obs, ~ending.running)
        ending.update(obs, phase, controls)
        history.record(obs, np.where(ending.running, phase, SETTLE_PHASE), controls, was_done)
        if recorder is not None:
            recorder.log_control_step(step=step, time=obs.time, positions=obs.positions, sampled=obs.sampled,
                                      rows=history.rows, done=was_done)
        if progress is not None:
            progress(step, s.max_steps + s.max_settle_steps, int(ending.done.sum()), W)
        if ending.done.all():
            return jam_steps
        controls = _apply(sim, observer, law, ending, obs, controls, jam_steps)
        sim.step(s.control_period)
        step += 1


def _result(w: int, ending: _Ending, history: History, jam_steps: np.ndarray, design: Design, target: TriMesh,
            passive_ipams: np.ndarray, passive_cells: np.ndarray) -> ControlResult:
    obs, controls = ending.final[w]
    x, sampled = obs.positions[w].copy(), obs.sampled[w].copy()
    vol, vol_t = obs.volume[w], obs.target_volume[w]
    saturated = ending.saturated(w)
    return ControlResult(
        achieved=design.rest.copy_with(x), sampled_target=design.rest.copy_with(sampled),
        objective=float(obs.objective[w]), pcc=float(obs.pcc[w]), mare=float(obs.mare[w]), mpre=float(obs.mpre[w]),
        volume_error=float((vol - vol_t) / vol_t), ipam_forces=obs.ipam_forces[w].copy(),
        ipam_pressures=controls.pressures[w].copy(), air_moles=float(controls.air[w]),
        jammed=obs.jammed[w].copy().astype(bool), jam_steps=jam_steps[w].copy(),
        converged=bool(ending.cause[w] == "deadbands" and ending.final_met[w] and ending.settled[w] and not saturated),
        reason=ending.reason(w, saturated), saturated=saturated, settled=bool(ending.settled[w]),
        max_speed=float(obs.max_speed[w]), control_steps=int(obs.step),
        history=history.columns(w), settings=ending.settings, frames=history.frame_stack(w), design=design,
        target=target, passive_ipams=np.flatnonzero(passive_ipams[w]), passive_cells=np.flatnonzero(passive_cells[w]))


def run_law(design: Design, targets: list[TriMesh], law, *, device: str, settings: ControlSettings, recorder=None,
            progress=None, passive_ipams=(), passive_cells=(), target_names=None,
            recorder_prefix: str = "control", keep_simulator: bool = False):
    """Drive ``design`` to every (centred) target at once with the control law ``law`` (a class of
    ``LAWS``), one simulated world per target; the arguments are those of ``control_many``.
    Returns the results, and with ``keep_simulator`` also the simulator at the end of the run (every
    world where ``controller.open_loop.replay_simulator`` of the results puts it, bit for bit)."""
    W = len(targets)
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(W)]
    problem = as_problem(targets, names, device=device, centre=False)
    sampler = problem.sampler  # built (and star-shapes checked) once per problem
    problem.check_rest(design.rest, settings.max_stretch)  # once per rest shape in the problem's run
    sim = _simulator(design, settings.simulation, device, W)
    host = sim.model.host
    passive_i = _passive_mask(passive_ipams, W, host.n_ipams, "passive_ipams")  # (W, n_ipam)
    passive_c = _passive_mask(passive_cells, W, host.n_cells, "passive_cells")  # (W, n_cell)
    mask_passive(sim, passive_i, passive_c)
    if recorder is not None:
        recorder.begin_run(design=design, targets=targets, target_names=names, prefix=recorder_prefix,
                           settings=settings)
    ending, history = _Ending(settings, host, passive_i), History(W, host)
    observer = Observer(host, sampler, W, [t.volume() for t in targets])
    jam_steps = _run(sim, observer, law(settings, host, passive_i, passive_c), ending, history, progress=progress,
                     recorder=recorder)
    results = [_result(w, ending, history, jam_steps, design, targets[w], passive_i, passive_c) for w in range(W)]
    if recorder is not None:
        recorder.end_run(results)
    return (results, sim) if keep_simulator else results
