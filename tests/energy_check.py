"""A force family's forces against central differences of its own energy (float64 simulators)."""

from __future__ import annotations

import numpy as np
import pytest


def assert_force_is_minus_energy_gradient(sim, family: str, x0: np.ndarray, vertices, *, h: float = 1e-7,
                                          rel: float = 1e-5, abs_tol: float = 1e-9) -> None:
    """Every coordinate of ``vertices``: ``sim.forces(family)`` at ``x0`` equals minus the central
    difference (step ``h``, m) of ``sim.energy()[family]``; the positions are left at ``x0``."""
    sim.positions = x0
    force = sim.forces(family)
    for v in vertices:
        for c in range(3):
            e = []
            for s in (1, -1):
                x = x0.copy()
                x[v, c] += s * h
                sim.positions = x
                e.append(sim.energy()[family])
            assert force[v, c] == pytest.approx(-(e[0] - e[1]) / (2 * h), rel=rel, abs=abs_tol), (family, v, c)
    sim.positions = x0
