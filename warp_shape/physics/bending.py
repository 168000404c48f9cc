"""Hinge bending: launch wrapper, dihedral angles, energy and the angle gradient for the stable step."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from warp_shape.kernels import bending as kb

from . import Launch
from .bending_law import dihedral_angles_np

if TYPE_CHECKING:
    from ..model import Model, State

__all__ = ["eval_bending", "bending_energy_np", "hinge_gradient_norms", "bending_rows_np",
           "hinge_gradients_np"]


def eval_bending(model: Model, state: State, x, f, launch: Launch, paper: bool = False):
    """Add hinge bending forces at x (W, V) into f (each hinge's k_t from the state: jam factor
    applied); launches nothing when k_t = 0."""
    if not model.has_bending:
        return
    launch(kb.eval_bending_kernel, (x.shape[0], model.n_edges),
           [model.hinges, int(paper), x, state.rest_angle, state.bend_stiffness, f])


def bending_energy_np(x: np.ndarray, hinges: np.ndarray, rest_angle: np.ndarray, kt: np.ndarray) -> np.ndarray:
    """(W,) bending energy sum 0.5 k_t (theta - theta_0)^2 in J; x (W, V, 3), rest_angle and kt (W, E)."""
    return 0.5 * np.sum(kt * (dihedral_angles_np(x, hinges) - rest_angle) ** 2, axis=1)


def hinge_gradient_norms(x: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """(E, 4) norms of d(theta)/dx for each hinge vertex, at positions x (V, 3)."""
    x0, x1, x2, x3 = (x[hinges[:, k]] for k in range(4))
    e = x1 - x0
    len_e = np.linalg.norm(e, axis=1)
    h2 = np.linalg.norm(np.cross(e, x2 - x0), axis=1) / len_e
    h3 = np.linalg.norm(np.cross(x0 - x1, x3 - x1), axis=1) / len_e
    g2, g3 = 1.0 / h2, 1.0 / h3
    t2 = np.einsum("ij,ij->i", x2 - x0, e) / len_e**2
    t3 = np.einsum("ij,ij->i", x3 - x0, e) / len_e**2
    g1 = np.abs(t2) * g2 + np.abs(t3) * g3
    g0 = np.abs(1 - t2) * g2 + np.abs(1 - t3) * g3
    return np.stack([g0, g1, g2, g3], axis=1)


def bending_rows_np(rows: np.ndarray, hinges: np.ndarray, kt: np.ndarray, rest_vertices: np.ndarray,
                    inv_sqrt: np.ndarray) -> None:
    """Add the Gershgorin row sums of M^-1/2 K M^-1/2 of the hinges' Gauss-Newton stiffness
    k_t g g^T (g = d(theta)/dx at the rest geometry, frozen per model) to rows (W, V); kt (W, E)."""
    g = hinge_gradient_norms(rest_vertices, hinges)
    gs = g * inv_sqrt[hinges]  # |g_a| / sqrt(m_a)
    total = gs.sum(axis=1)
    for w in range(rows.shape[0]):
        for c in range(4):
            np.add.at(rows[w], hinges[:, c], kt[w] * gs[:, c] * total)


def hinge_gradients_np(xT: np.ndarray, hinges: np.ndarray) -> list:
    """d(theta)/dx of every hinge at positions xT (3, V): four (3, E) arrays for v0, v1, v2, v3
    (the wings along their face normals over the distance to the edge, the edge vertices by the
    lever rule), as the exact bending forces use them."""
    x0, x1, x2, x3 = (xT[:, hinges[:, c]] for c in range(4))
    e = x1 - x0
    ee = np.maximum((e * e).sum(axis=0), 1e-300)
    le = np.sqrt(ee)
    n_a = np.cross(e, x2 - x0, axis=0)
    n_b = np.cross(x0 - x1, x3 - x1, axis=0)
    g2 = -n_a * (le / np.maximum((n_a * n_a).sum(axis=0), 1e-300))
    g3 = -n_b * (le / np.maximum((n_b * n_b).sum(axis=0), 1e-300))
    t2 = ((x2 - x0) * e).sum(axis=0) / ee
    t3 = ((x3 - x0) * e).sum(axis=0) / ee
    g1 = -(g2 * t2 + g3 * t3)
    g0 = -(g2 * (1.0 - t2) + g3 * (1.0 - t3))
    return [g0, g1, g2, g3]
