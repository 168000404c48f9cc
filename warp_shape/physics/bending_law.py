"""Hinge geometry in float64 on plain arrays: the signed dihedral angle of each hinge.

Part of the bending family's home (with ``kernels/bending.py`` and ``physics/bending.py``) that imports
no Warp kernel and no model, so the host model's rest angles use it without the kernels.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dihedral_angles_np"]


def dihedral_angles_np(x: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Signed dihedral angles (float64) of hinges (v0, v1 | v2, v3); x is (..., V, 3)."""
    x0, x1, x2, x3 = (x[..., hinges[:, k], :] for k in range(4))
    e = x1 - x0
    n_a = np.cross(e, x2 - x0)
    n_b = np.cross(x0 - x1, x3 - x1)
    len_e = np.linalg.norm(e, axis=-1)
    sin_t = np.einsum("...i,...i->...", np.cross(n_a, n_b), e) / len_e
    cos_t = np.einsum("...i,...i->...", n_a, n_b)
    return np.arctan2(sin_t, cos_t)
