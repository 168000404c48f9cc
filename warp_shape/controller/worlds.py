"""Worlds of a batch: the actuators each world leaves out, and each world's largest speed.

(A model-based controller copies the state of one simulated world into many worlds of a batch on
the device: ``Simulator.snapshot`` and ``Simulator.load_worlds``, ``model.copy_worlds``.)
"""

from __future__ import annotations

import numpy as np

__all__ = ["max_speeds", "mask_passive", "passive_masks"]


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
