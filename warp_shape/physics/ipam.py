"""IPAM actuators: launch wrapper and the host-side law (lengths, natural length, force, energy, bound)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from warp_shape.kernels import ipam as kip

from . import Launch
from .springs import spring_rows_np

if TYPE_CHECKING:
    from ..model import Control, HostModel, Model

__all__ = ["eval_ipams", "ipam_lengths_np", "centroid_distances_np", "natural_length_np", "axial_force_np", "pressure_for_length_np",
           "ipam_energy_np", "ipam_rows_np", "ipam_operator_terms"]


def eval_ipams(model: Model, x, v, control: Control, f, launch: Launch):
    """Add IPAM sub-spring forces at (x, v) (W, V) into f (none from an IPAM masked out of a world,
    ``control.ipam_enabled``); launches nothing without IPAMs."""
    if not model.has_ipams:
        return
    launch(kip.eval_ipam_kernel, (x.shape[0], 3 * model.n_ipams),
           [model.ipam_sub_pairs, model.ipam_sub_offsets, model.ipam_stiffness, model.ipam_area_over_k,
            model.ipam_free_length, model.ipam_damping, x, v, control.ipam_pressure, control.ipam_enabled, f])


def ipam_lengths_np(x: np.ndarray, faces: np.ndarray, ipam_faces: np.ndarray) -> np.ndarray:
    """(W, n) IPAM lengths L in m: the distance between the centroids of each IPAM's end faces
    ipam_faces (n, 2), at positions x (W, V, 3)."""
    ends = faces[ipam_faces.reshape(-1)]  # (2 n, 3): a0, b0, a1, b1, ...
    return centroid_distances_np(x[:, ends].mean(axis=2).reshape(x.shape[0], -1, 2, 3), None)


def centroid_distances_np(centroids: np.ndarray, ipam_faces: np.ndarray | None) -> np.ndarray:
    """(W, n) distance between the end-face centroids of each IPAM: ``centroids`` (W, F, 3) of every
    face with ``ipam_faces`` (n, 2), or (W, n, 2, 3) of the end faces already paired (ipam_faces None)."""
    if ipam_faces is not None:
        centroids = centroids[:, ipam_faces]
    return np.linalg.norm(centroids[:, :, 1] - centroids[:, :, 0], axis=-1)


def natural_length_np(free_length, area_over_k, pressure):
    """Natural length L_n = L0 + (A/k) P in m at gauge pressure P (Pa); broadcasts."""
    return free_length + area_over_k * pressure


def axial_force_np(k, length, natural):
    """Axial force F = k (L - L_n) in N, positive = tension; broadcasts."""
    return k * (length - natural)


def pressure_for_length_np(free_length, area_over_k, length):
    """Gauge pressure (Pa) at which the natural length equals ``length`` (inverse of natural_length_np)."""
    return (length - free_length) / area_over_k


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
