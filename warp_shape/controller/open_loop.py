"""Replay recorded control sequences open loop, from rest, as a valve controller would.

A control result's history holds one row per control step: the time, the controls in force since
the previous row (``air_mol``, ``ipam{i}_pressure_pa``) and the jam state measured at the row
(``cell{j}_jammed``). Replaying starts a simulator of the design at rest and, for every row after
the first, jams the cells that the row shows newly jammed (they were jammed at the previous row),
sets the row's controls and steps until the row's time. Nothing is measured or fed back.

On the CPU a result of a single-target run (``control``) replays bit for bit: the same state,
the same settings and the same calls give the same floating-point operations. The worlds of a batch
(``control_many``) share one internal step count, the smallest stable one over the batch, so one of
them replayed alone can take other internal steps; ``replay_simulator`` with the whole batch
replays it exactly.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..display import Design
from ..errors import DesignError
from ..sampling import RadialSampler
from ..simulator import Simulator
from .history import History
from .laws import Controls
from .observe import Observer
from .result import ControlResult
from .worlds import mask_passive, passive_masks

__all__ = ["replay", "replay_result", "replay_simulator", "control_schedule", "drive_schedules", "family_schedule"]


def control_schedule(result, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(steps (n,), air (n,), pressures (n, n_ipam), jammed (n, n_cell)) of a result's rows: the
    simulation steps from rest to each row and the controls and jam state at it."""
    h = result.history
    n_ipam, n_cell = len(result.ipam_pressures), len(result.jammed)
    steps = np.rint(np.asarray(h["time"], dtype=np.float64) / dt).astype(np.int64)
    if steps[0] != 0 or np.any(np.diff(steps) < 0):
        raise DesignError("a replayable history starts at time 0 and never goes back in time")
    air = np.asarray(h["air_mol"], dtype=np.float64)
    p = np.stack([h[f"ipam{i}_pressure_pa"] for i in range(n_ipam)], 1) if n_ipam else np.zeros((len(air), 0))
    jam = np.stack([h[f"cell{j}_jammed"] for j in range(n_cell)], 1).astype(bool) if n_cell \
        else np.zeros((len(air), 0), bool)
    return steps, air, p, jam


def family_schedule(result, model) -> dict:
    """{family name: (rows, n) controls} of every actuator family of ``model`` but the IPAM (whose
    pressures ``control_schedule`` gives) that has elements: each row's controls, from the history
    column the family names (``ActuatorFamily.control_column``); a missing column is an error naming it."""
    out = {}
    for fam in model.families:
        n = model.host.count(fam.name)
        if not fam.controlled or fam.name == "ipam" or not n:
            continue
        cols = [fam.control_column.format(i=i) for i in range(n)]
        missing = [c for c in cols if c not in result.history]
        if missing:
            raise DesignError(f"the result's history has no column {missing[0]!r} (the {fam.control_name} of its "
                              f"{fam.plural}): it was recorded on a design without them; control this design first")
        out[fam.name] = np.stack([np.asarray(result.history[c], dtype=np.float64) for c in cols], 1)
    return out


def replay_simulator(design: Design, results, *, device: str = "cpu"):
    """A simulator with one world per result (all of ``design``, same simulation settings) after
    replaying every result's control sequence from rest; worlds whose sequence ends earlier hold
    their last controls while the others run on."""
    if not isinstance(design, Design):
        raise DesignError(f"replay needs a ws.Design, got {type(design).__name__}")
    results = list(results) if isinstance(results, (list, tuple)) else [results]
    bad = [type(r).__name__ for r in results if not isinstance(r, ControlResult)]
    if bad:
        raise DesignError(f"replay needs control results (ws.control(...) returns one), got {bad[0]}")
    if not results:
        raise DesignError("replay needs at least one control result")
    sim_settings = results[0].settings.simulation
    sim = Simulator(design, device=device, settings=sim_settings, worlds=len(results))
    sched = [control_schedule(r, sim.dt) for r in results]
    if any(s[3].shape[1] != design.n_cells or s[2].shape[1] != design.n_ipams for s in sched):
        raise DesignError("the result was recorded on a design with other IPAMs or cells than the one given")
    # actuators a sequence left out are masked out, as when it was recorded
    mask_passive(sim, *passive_masks(results, design.n_ipams, design.n_cells))
    drive_schedules(sim, sched, families=[family_schedule(r, sim.model) for r in results])
    return sim


def drive_schedules(sim, schedules, end: int | None = None, after=None, families=None) -> None:
    """Step ``sim`` (one world per schedule, from its state at step 0) through ``schedules``, each
    (steps, air, pressures, jammed) as ``control_schedule`` gives them: before each row's step, the
    cells the row shows newly jammed are jammed and its controls set, then the simulator steps to the
    next row of any world; a world whose schedule ended holds its last controls. ``end``: on to that
    step, every world holding its last controls. ``after(step)``: called at every row reached.
    ``families``: per schedule, the other actuator families' controls per row (``family_schedule``),
    set with the row's air and pressures."""
    n = len(schedules)
    marks = np.unique(np.concatenate([s[0] for s in schedules] + ([[end]] if end is not None else [])))
    for a, b in zip(marks[:-1], marks[1:]):
        rows = [min(int(np.searchsorted(s[0], b)), len(s[0]) - 1) for s in schedules]  # the row ending at b
        jammed = np.asarray(sim.jammed).reshape(n, -1)
        for w, (s, k) in enumerate(zip(schedules, rows)):
            for j in np.flatnonzero(s[3][k] & ~jammed[w]):
                sim.jam(int(j), world=w)
        sim.air_moles = np.array([s[1][k] for s, k in zip(schedules, rows)])
        if schedules[0][2].shape[1]:
            sim.ipam_pressures = np.stack([s[2][k] for s, k in zip(schedules, rows)])
        for name in (families[0] if families else {}):
            sim.set_actuator_controls(name, np.stack([f[name][k] for f, k in zip(families, rows)]))
        sim.step(int(b - a))
        if after is not None:
            after(int(b))


def replay(design: Design, result, *, device: str = "cpu") -> np.ndarray:
    """(V, 3) float64 positions, m, at the end of ``result``'s control sequence replayed open loop
    from rest on ``design``."""
    return np.asarray(replay_simulator(design, [result], device=device).positions).reshape(-1, 3)


def replay_result(design: Design, result, *, device: str = "cpu") -> ControlResult:
    """``result`` as its sequence plays open loop on ``design`` (another design of the same actuators
    and cells, e.g. a co-designed one): the same controls, jam events and rows, and the membrane, fit
    and forces measured at every row of the replay. ``converged`` also asks the replay to end at rest."""
    target = result.target
    if target is None:
        raise DesignError("replay_result needs a result that carries its target (control results do)")
    sim = Simulator(design, device=device, settings=result.settings.simulation, worlds=1)
    sched = control_schedule(result, sim.dt)
    if sched[3].shape[1] != design.n_cells or sched[2].shape[1] != design.n_ipams:
        raise DesignError("the result was recorded on a design with other IPAMs or cells than the one given")
    mask_passive(sim, *passive_masks([result], design.n_ipams, design.n_cells))
    host = sim.model.host
    observer = Observer(host, RadialSampler(target, device=device), 1, [target.volume()])
    history = History(1, host)
    steps, air, press, _ = sched
    phases = np.asarray(result.history["phase"])
    last = []

    def observe(step: int) -> None:
        k = int(np.searchsorted(steps, step))
        controls = Controls(air=air[k:k + 1], pressures=press[k:k + 1])
        obs = observer.observe(sim, k, controls.air, controls.pressures)
        history.record(obs, phases[k:k + 1], controls, np.zeros(1, bool))
        last[:] = [obs]

    observe(0)
    drive_schedules(sim, [sched], after=observe, families=[family_schedule(result, sim.model)])
    obs = last[0]
    x, sampled = obs.positions[0].copy(), obs.sampled[0].copy()
    settled = bool(obs.max_speed[0] < result.settings.settle_speed)
    rest = "at rest" if settled else (f"not at rest ({obs.max_speed[0] * 1e3:.2f} mm/s >= "
                                      f"{result.settings.settle_speed * 1e3:g} mm/s), so not converged")
    return dataclasses.replace(
        result, achieved=design.rest.copy_with(x), sampled_target=design.rest.copy_with(sampled),
        objective=float(obs.objective[0]), pcc=float(obs.pcc[0]), mare=float(obs.mare[0]), mpre=float(obs.mpre[0]),
        volume_error=float((obs.volume[0] - obs.target_volume[0]) / obs.target_volume[0]),
        ipam_forces=obs.ipam_forces[0].copy(), jammed=obs.jammed[0].copy().astype(bool),
        converged=bool(result.converged and settled), settled=settled, max_speed=float(obs.max_speed[0]),
        reason=f"as controlled: {result.reason}; its sequence replayed open loop on this design: {rest}",
        history=history.columns(0),
        frames=history.frame_stack(0), design=design)
