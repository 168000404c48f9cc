"""Particle jamming: the launch that freezes and stiffens a cell's edges, and the jam factor law."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from warp_shape.kernels import jamming as kj

from . import Launch

if TYPE_CHECKING:
    from ..model import Model, State

__all__ = ["eval_jam", "jammed_factor_np"]


def eval_jam(model: Model, state: State, cell: int, world_mask, launch: Launch):
    """Jam cell ``cell`` in the worlds where world_mask (W,) int32 is 1: its edges keep their current
    length and angle as rest values and are stiffened (an edge already jammed is left as it is), and so
    do the elements of every family that jams (the hyperelastic membrane's triangles)."""
    edges = model.cell_edges[cell]
    launch(kj.jam_edges_kernel, (state.worlds, edges.shape[0]),
           [model.hinges, edges, world_mask, model.scalar(model.jam_stretch_factor),
            model.scalar(model.jam_bend_factor), state.x, state.edge, state.jammed])
    for fam in model.families:
        if fam.jams and fam.name in state.family_jam:
            fam.jam(model, state, cell, world_mask, launch)


def jammed_factor_np(jammed: np.ndarray, factor: float) -> np.ndarray:
    """Stiffness multiplier of each edge: ``factor`` where jammed, 1 elsewhere (float64, jammed's shape)."""
    return np.where(jammed, factor, 1.0)
