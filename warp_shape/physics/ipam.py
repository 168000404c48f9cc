"""IPAM actuators: launch wrapper and the model's host-side terms (energy, stability rows and operator).

The law itself (lengths, natural length, axial force, its inverse) is in ``ipam_law``, free of Warp
kernels, so the host-side ``Design`` can use it."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from warp_shape.kernels import ipam as kip

from . import Launch
from .ipam_law import natural_length_np
from .springs import spring_rows_np

if TYPE_CHECKING:
    from ..model import Control, HostModel, Model

__all__ = ["eval_ipams", "ipam_energy_np", "ipam_rows_np", "ipam_operator_terms"]


def eval_ipams(model: Model, x, v, control: Control, f, launch: Launch):
    """Add IPAM sub-spring forces at (x, v) (W, V) into f (none from an IPAM masked out of a world,
    ``control.ipam_enabled``); launches nothing without IPAMs."""
    if not model.has_ipams:
        return
    launch(kip.eval_ipam_kernel, (x.shape[0], 3 * model.n_ipams),
           [model.ipam_sub_pairs, model.ipam_sub_offsets, model.ipam_stiffness, model.ipam_area_over_k,
            model.ipam_free_length, model.ipam_damping, x, v, control.ipam_pressure, control.ipam_enabled, f])


def ipam_energy_np(x: np.ndarray, host: HostModel, pressure: np.ndarray, enabled: np.ndarray | None = None) -> np.ndarray:
    """(W,) elastic energy of the IPAM sub-springs in J at positions x (W, V, 3) and gauge pressures
    (W, n): three springs of stiffness k/3 each, natural length L_n + the sub-spring's rest offset;
    none from an IPAM masked out of a world (``enabled`` (W, n) bool False)."""
    pairs = host.ipam_sub_pairs
    natural = natural_length_np(host.ipam_free_length, host.ipam_area_over_k, pressure)
    natural = np.repeat(natural, 3, axis=1) + host.ipam_sub_offsets
    d = np.linalg.norm(x[:, pairs[:, 1]] - x[:, pairs[:, 0]], axis=-1)
    e = np.repeat(host.ipam_stiffness / 3.0, 3) * (d - natural) ** 2
    if enabled is not None:
        e = e * np.repeat(np.asarray(enabled, dtype=np.float64), 3, axis=1)
    return 0.5 * np.sum(e, axis=1)


def ipam_rows_np(stiff: np.ndarray, damp: np.ndarray, host: HostModel, inv_m: np.ndarray,
                 inv_sqrt: np.ndarray) -> None:
    """Add the sub-springs' Gershgorin stiffness rows to stiff (W, V) and their dampers' rows to damp."""
    W = stiff.shape[0]
    pairs = host.ipam_sub_pairs
    k_sub = np.repeat(host.ipam_stiffness / 3.0, 3)
    c_sub = np.repeat(host.ipam_damping, 3)
    spring_rows_np(stiff, pairs[:, 0], pairs[:, 1], np.broadcast_to(k_sub, (W, k_sub.size)), inv_m, inv_sqrt)
    spring_rows_np(damp, pairs[:, 0], pairs[:, 1], np.broadcast_to(c_sub, (W, c_sub.size)), inv_m, inv_sqrt)


def ipam_operator_terms(xT: np.ndarray, host: HostModel):
    """(a, b, axial k, transverse k, directions (3, n)) of the sub-springs for the elastic operator at
    positions xT (3, V). The transverse stiffness k |1 - L_n / L| is bounded by k while
    0 <= L_n <= 2 L (as in the Gershgorin bound), so k is used."""
    pairs = host.ipam_sub_pairs
    dp = xT[:, pairs[:, 1]] - xT[:, pairs[:, 0]]
    lp = np.maximum(np.sqrt((dp * dp).sum(axis=0)), 1e-300)
    k_sub = np.repeat(host.ipam_stiffness / 3.0, 3)
    return pairs[:, 0], pairs[:, 1], k_sub, k_sub, dp / lp
