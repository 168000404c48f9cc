"""Replay of observation sequences on a model, one world per sequence, each then held until at rest."""

from __future__ import annotations

import numpy as np

from ..controller.open_loop import drive_schedules
from ..controller.worlds import mask_passive, max_speeds
from ..display import Design
from ..simulator import Simulator
from .observations import Sequence

__all__ = ["HOLD_S", "replay_held"]

#: seconds every sequence's last controls are held before the scan (the membrane comes to rest: a
#: step of the air to 1.6 x rest slows to 2e-5 m/s within 0.4 s on the 162-vertex Fig. 6 device)
HOLD_S = 0.4
#: after ``HOLD_S`` the controls stay held, in chunks of ``SETTLE_CHUNK`` output steps, until every
#: vertex moves slower than this (m/s): what is left of the motion is then nanometres, so replays
#: with slightly different parameters (finite differences) differ by their equilibria, not their transients
SETTLE_SPEED = 1e-6
SETTLE_CHUNK = 50
#: most seconds held in all
MAX_HOLD_S = 3.0


def _passive(seqs: list[Sequence], n: int, attr: str) -> np.ndarray:
    out = np.zeros((len(seqs), n), bool)
    for w, s in enumerate(seqs):
        out[w, np.asarray(getattr(s, attr), np.int64)] = True
    return out


def replay_held(design: Design, seqs: list[Sequence], *, hold_s: float = HOLD_S, precision: str = "float64",
                device: str = "cpu", pressures: bool = False):
    """(W, V, 3) float64 positions, m: every sequence of ``seqs`` replayed open loop from rest on
    ``design`` (one world each, the first sequence's simulation settings at ``precision``), as
    ``ws.replay`` does, then its last controls held for ``hold_s`` seconds and on until at rest
    (``SETTLE_SPEED``, at most ``MAX_HOLD_S`` in all). With ``pressures`` also (W,) the chamber's
    gauge pressure at the end, Pa."""
    settings = seqs[0].simulation.replace(precision=precision)
    sim = Simulator(design, device=device, settings=settings, worlds=len(seqs))
    mask_passive(sim, _passive(seqs, design.n_ipams, "passive_ipams"), _passive(seqs, design.n_cells, "passive_cells"))
    dt = sim.dt
    sched = [(np.rint(s.times / dt).astype(np.int64), s.air, s.pressures, s.jammed) for s in seqs]
    end = max(int(st[0][-1]) for st in sched) + int(round(hold_s / dt))
    limit = end + int(round(max(MAX_HOLD_S - hold_s, 0.0) / dt))
    drive_schedules(sim, sched, end)
    while max_speeds(sim).max() > SETTLE_SPEED and end < limit:
        sim.step(SETTLE_CHUNK)
        end += SETTLE_CHUNK
    x = np.asarray(sim.positions, dtype=np.float64).reshape(len(seqs), -1, 3)
    return (x, np.atleast_1d(np.asarray(sim.pressure(), dtype=np.float64))) if pressures else x
