"""World states as host data: take one world of a simulator, put it into worlds of another.

A model-based controller explores from a state: it copies the state of one simulated world
(positions, velocities, the jammed rest values and stiffnesses of every edge, which cells are
jammed, the air amount and the IPAM pressures) into many worlds of a batch, perturbs one control in
each and simulates them all at once (one launch per kernel for every world).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WorldState", "take_worlds", "put_worlds", "max_speeds", "mask_passive", "passive_masks"]


@dataclass(frozen=True)
class WorldState:
    """Everything that makes one simulated world's future (host copies, the simulator's dtypes)."""

    xv: np.ndarray  # (2, V, 3) positions (m) and velocities (m/s)
    edge: np.ndarray  # (4, E) rest length, rest angle, stretch and bend stiffness (jam factors applied)
    edge_jammed: np.ndarray  # (E,) int32, 1 where an edge is jammed
    cell_jammed: np.ndarray  # (n_cell,) bool
    cell_jam_time: np.ndarray  # (n_cell,) s, NaN where not jammed
    air: float  # mol
    pressures: np.ndarray  # (n_ipam,) gauge Pa

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) positions as float64, m."""
        return self.xv[0].astype(np.float64)


def take_worlds(sim, worlds=None) -> list[WorldState]:
    """The states of ``worlds`` (default all) of ``sim``."""
    st = sim.state
    xv, edge, ej = st.xv.numpy(), st.edge.numpy(), st.jammed.numpy()
    air = np.atleast_1d(sim.air_moles)
    n_ipam = sim.model.n_ipams
    p = np.asarray(sim.ipam_pressures).reshape(sim.worlds, n_ipam) if n_ipam else np.zeros((sim.worlds, 0))
    ws = range(sim.worlds) if worlds is None else worlds
    return [WorldState(xv=xv[:, w].copy(), edge=edge[:, w].copy(), edge_jammed=ej[w].copy(),
                       cell_jammed=st.cell_jammed[w].copy(), cell_jam_time=st.cell_jam_time[w].copy(),
                       air=float(air[w]), pressures=p[w].copy()) for w in ws]


def put_worlds(sim, states: list[WorldState]) -> None:
    """Load one state per world of ``sim`` (``len(states) == sim.worlds``); time is left as it is."""
    if len(states) != sim.worlds:
        raise ValueError(f"put_worlds needs one state per world ({sim.worlds}), got {len(states)}")
    st = sim.state
    st.edge.assign(np.stack([s.edge for s in states], axis=1))
    st.jammed.assign(np.stack([s.edge_jammed for s in states]))
    st.cell_jammed[:] = np.stack([s.cell_jammed for s in states])
    st.cell_jam_time[:] = np.stack([s.cell_jam_time for s in states])
    xv = np.stack([s.xv for s in states], axis=1)
    sim.positions = xv[0]  # also tells the simulator to re-estimate its stable step
    sim.velocities = xv[1]
    sim.air_moles = np.array([s.air for s in states])
    if sim.model.n_ipams:
        sim.ipam_pressures = np.stack([s.pressures for s in states])


def passive_masks(results, n_ipam: int, n_cell: int) -> tuple[np.ndarray, np.ndarray]:
    """((W, n_ipam), (W, n_cell)) bool, True where control result w leaves the IPAM or cell out."""
    pi, pc = np.zeros((len(results), n_ipam), bool), np.zeros((len(results), n_cell), bool)
    for w, r in enumerate(results):
        pi[w, np.asarray(r.passive_ipams, dtype=np.int64)] = True
        pc[w, np.asarray(r.passive_cells, dtype=np.int64)] = True
    return pi, pc


def mask_passive(sim, passive_ipams: np.ndarray | None, passive_cells: np.ndarray | None = None):
    """Mask the actuators a control sequence leaves out ((W, n_ipam) / (W, n_cell) bool, True =
    passive) out of the worlds of ``sim``: a passive IPAM exerts no force, a passive cell never jams
    (the paper, section V-C: an actuator can be neutralised). Returns ``sim``."""
    if passive_ipams is not None and sim.model.n_ipams:
        sim.ipam_mask = ~np.asarray(passive_ipams, dtype=bool).reshape(sim.worlds, -1)
    if passive_cells is not None and sim.model.n_cells:
        sim.cell_mask = ~np.asarray(passive_cells, dtype=bool).reshape(sim.worlds, -1)
    return sim


def max_speeds(sim) -> np.ndarray:
    """(W,) the largest vertex speed of every world, m/s."""
    v = sim.state.v.numpy().reshape(sim.worlds, -1, 3)
    return np.sqrt((v.astype(np.float64) ** 2).sum(axis=2).max(axis=1))
