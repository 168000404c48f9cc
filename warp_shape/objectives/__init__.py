"""Objectives: what a run minimises, registered by name, each in one file.

An ``Objective`` gives, for a membrane against a target sampled radially: its per-sample errors, the
weighted residual vector whose norm is its value (what Gauss-Newton steps on), its value for one world
and for a batch of worlds, and its derivative with respect to the membrane's vertex positions (what the
differentiable replay's adjoint starts from). The controller's stopping rule and model-based steps, the
designer's placements and co-design, the reports and the calibration's closing-the-loop checks use the
fit objective through it; ``OBJECTIVES`` holds it by name (``"scaled_radial"``, ``objectives/radial.py``),
and a second objective (felt stiffness) registers beside it.
"""

from __future__ import annotations

import numpy as np

from ..registry import Registry

__all__ = ["Objective", "OBJECTIVES"]


class Objective:
    """A registered objective. ``name``: identifier; ``summary``: one line; ``unit``: of its value."""

    name = ""
    summary = ""
    unit = ""

    def errors(self, r: np.ndarray, R: np.ndarray, volume: float) -> np.ndarray:
        """Per-sample errors of design radii r against sampled target radii R (same shape), for a target
        of ``volume`` m^3."""
        raise NotImplementedError

    def residuals(self, r: np.ndarray, R: np.ndarray, weights: np.ndarray, volume: float) -> np.ndarray:
        """The residual vector whose Euclidean norm is ``value`` (``weights``: each sample's area share)."""
        raise NotImplementedError

    def value(self, r: np.ndarray, R: np.ndarray, volume: float, weights=None) -> float:
        """The objective of one world."""
        raise NotImplementedError

    def values(self, r: np.ndarray, R: np.ndarray, volumes: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """(W,) the objective of each world of (W, N) radii."""
        raise NotImplementedError

    def gradient(self, x: np.ndarray, sampler, target_index: int, faces: np.ndarray, volume: float):
        """(value, d value / d x (V, 3)) of membrane positions x against target ``target_index`` of ``sampler``."""
        raise NotImplementedError


#: every objective, by name; the fit objective (``objectives.radial.SCALED_RADIAL``) first
OBJECTIVES = Registry("objective")
