"""Viscous damping: it starts every force evaluation (f = -c_v v), and its damping-rate bound."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from warp_shape.kernels import common as kc

from . import Launch

if TYPE_CHECKING:
    from ..model import Model

__all__ = ["eval_init_viscous", "eval_init_step", "viscous_rows_np"]


def eval_init_viscous(model: Model, v, f, volume, launch: Launch, enabled: bool = True):
    """Start a per-family force evaluation: f = -c_v v (or 0 without the viscous term), volume zeroed."""
    c_v = model.viscous_damping if enabled else 0.0
    launch(kc.init_forces_viscous, f.shape, [model.scalar(c_v), v, f, volume])


def eval_init_step(model: Model, xv, fg, volume2d, launch: Launch):
    """Start a fused evaluation: forces = -c_v v, dV/dx = 0 and every volume slot zeroed.
    xv and fg are packed (2, W, V) buffers: (positions, velocities) and (forces, dV/dx)."""
    _, W, V = fg.shape
    launch(kc.init_step_forces, (W * V,), [model.scalar(model.viscous_damping), W, V, xv, fg, volume2d])


def viscous_rows_np(viscous_damping: float, inv_m: np.ndarray) -> np.ndarray:
    """(1, V) damping rates c_v / m of the viscous term, s^-1 (to add to Gershgorin damping rows)."""
    return viscous_damping * inv_m[None, :]
