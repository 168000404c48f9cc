"""A bounded, damped Gauss-Newton step on a small least-squares problem (pure NumPy).

Minimise ``|e + J d|^2 + lam |d|^2`` over the step ``d`` with ``lo <= d <= hi`` (bounds already
shifted by the current controls): an active-set loop that solves the damped normal equations on the
free variables, fixes a variable that leaves its box at the bound it crossed, and frees a fixed one
whose gradient points back inside. With a handful of controls it ends in a few passes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bounded_step"]


def _solve_free(J: np.ndarray, e: np.ndarray, lam: float, d: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``d`` with its free entries set to the damped least-squares minimiser (fixed ones kept)."""
    out = d.copy()
    if not free.any():
        return out
    A = J[:, free]
    rhs = -(A.T @ (e + J[:, ~free] @ d[~free]))
    out[free] = np.linalg.solve(A.T @ A + lam * np.eye(A.shape[1]), rhs)
    return out


def bounded_step(J: np.ndarray, e: np.ndarray, lam: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The step ``d`` (m,) minimising ``|e + J d|^2 + lam |d|^2`` within ``lo <= d <= hi``.
    ``J``: (n, m), ``e``: (n,), ``lo <= 0 <= hi``."""
    m = J.shape[1]
    if np.any(lo > 1e-15) or np.any(hi < -1e-15):
        raise ValueError("bounded_step needs lo <= 0 <= hi")
    d = np.zeros(m)
    free = np.ones(m, dtype=bool)
    for _ in range(4 * m + 4):
        d = _solve_free(J, e, lam, d, free)
        out = free & ((d < lo) | (d > hi))
        if out.any():
            # fix the one that leaves its box first along the path from the feasible previous step
            d = np.clip(d, lo, hi)
            free &= ~out
            continue
        g = J.T @ (e + J @ d) + lam * d  # gradient of the objective / 2
        back = ~free & (((d <= lo) & (g > 0)) | ((d >= hi) & (g < 0)))
        if not back.any():
            break
        free |= back
    return np.clip(d, lo, hi)
