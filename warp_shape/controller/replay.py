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

import numpy as np

from ..design import Design
from ..errors import DesignError
from ..simulator import Simulator
from .result import ControlResult
from .worlds import mask_passive, passive_masks

__all__ = ["replay", "replay_simulator", "control_schedule", "drive_schedules"]


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
    drive_schedules(sim, sched)
    return sim


def drive_schedules(sim, schedules, end: int | None = None) -> None:
    """Step ``sim`` (one world per schedule, from its state at step 0) through ``schedules``, each
    (steps, air, pressures, jammed) as ``control_schedule`` gives them: before each row's step, the
    cells the row shows newly jammed are jammed and its controls set, then the simulator steps to the
    next row of any world; a world whose schedule ended holds its last controls. ``end``: on to that
    step, every world holding its last controls."""
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
        sim.step(int(b - a))


def replay(design: Design, result, *, device: str = "cpu") -> np.ndarray:
    """(V, 3) float64 positions, m, at the end of ``result``'s control sequence replayed open loop
    from rest on ``design``."""
    return np.asarray(replay_simulator(design, [result], device=device).positions).reshape(-1, 3)
