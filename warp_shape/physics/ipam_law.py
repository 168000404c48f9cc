"""The IPAM law in float64 on plain arrays: lengths, natural length, axial force and its inverse.

Part of the IPAM family's home (with ``kernels/ipam.py`` and ``physics/ipam.py``) that imports no
Warp kernel and no model, so the host-side ``Design`` uses the same law as the simulator and the
controller.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ipam_lengths_np", "centroid_distances_np", "natural_length_np", "axial_force_np", "pressure_for_length_np"]


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
