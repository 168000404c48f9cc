"""Edge springs and their dampers: launch wrapper, energy, edge lengths and stable-step terms."""

from __future__ import annotations

import numpy as np

from warp_shape.kernels import springs as ks

from . import Launch

# Model and State (warp_shape.model) are named in annotations only: importing them, even for type
# checking, would close a circle model -> physics.ipam (the IPAM family) -> springs -> model

__all__ = ["eval_springs", "edge_lengths_np", "spring_energy_np", "spring_rows_np", "spring_operator_terms"]


def eval_springs(model: Model, state: State, x, v, f, launch: Launch):
    """Add edge spring and damper forces at (x, v) (W, V) into f (jammed edges stiffened)."""
    s = model.scalar
    launch(ks.eval_spring_kernel, (x.shape[0], model.n_edges),
           [model.hinges, model.edge_stiffness, s(model.spring_damping), s(model.jam_stretch_factor), x, v,
            state.rest_length, state.jammed, f])


def edge_lengths_np(x: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """(..., E) edge lengths in m at positions x (..., V, 3); hinges (E, 4), the edge is v0 -> v1."""
    return np.linalg.norm(x[..., hinges[:, 1], :] - x[..., hinges[:, 0], :], axis=-1)


def spring_energy_np(x: np.ndarray, hinges: np.ndarray, rest_length: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(W,) elastic energy sum 0.5 k (L - L_rest)^2 in J; x (W, V, 3), rest_length and k (W, E) (k
    with jam factors applied, see jamming.jammed_factor_np)."""
    return 0.5 * np.sum(k * (edge_lengths_np(x, hinges) - rest_length) ** 2, axis=1)


def spring_rows_np(rows: np.ndarray, a: np.ndarray, b: np.ndarray, k: np.ndarray, inv_m: np.ndarray,
                   inv_sqrt: np.ndarray) -> None:
    """Add the Gershgorin row sums of M^-1/2 K M^-1/2 of 2-point springs k (W, n) between vertices
    a and b (n,) to rows (W, V); a damper c in place of k gives the damping-rate rows."""
    W = k.shape[0]
    for w in range(W):
        np.add.at(rows[w], a, k[w] * (inv_m[a] + inv_sqrt[a] * inv_sqrt[b]))
        np.add.at(rows[w], b, k[w] * (inv_m[b] + inv_sqrt[a] * inv_sqrt[b]))


def spring_operator_terms(xT: np.ndarray, a: np.ndarray, b: np.ndarray, k: np.ndarray, rest: np.ndarray):
    """Stiffness terms of 2-point springs for the elastic operator at positions xT (3, V): axial
    stiffness k, the tension's transverse stiffness |k (1 - L_rest / L)| and the unit directions
    (3, n) from a to b."""
    d = xT[:, b] - xT[:, a]
    length = np.maximum(np.sqrt((d * d).sum(axis=0)), 1e-300)
    return k, np.abs(k * (1.0 - rest / length)), d / length
