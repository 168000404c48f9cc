"""Ready-made designs used by the command line, the demo and the benchmarks."""

from __future__ import annotations

import numpy as np

from .display import Design
from .material import Material
from .mesh import icosphere

__all__ = ["cube_fig6_design", "corner_directions"]


def corner_directions() -> np.ndarray:
    """(4, 3) unit directions of four cube corners whose opposites complete the cube's 8 corners."""
    d = np.array([[1, 1, 1], [1, -1, 1], [-1, 1, 1], [-1, -1, 1]], dtype=np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _face_towards(centroids: np.ndarray, direction: np.ndarray, taken: set) -> int:
    unit = centroids / np.linalg.norm(centroids, axis=1, keepdims=True)
    # a symmetric mesh has faces exactly as close to a direction as others: rounding the score and
    # breaking ties by index makes the choice independent of floating-point summation order
    score = np.round(unit @ direction, 9)
    order = np.lexsort((np.arange(score.size), -score))
    for f in order:
        if int(f) not in taken:
            return int(f)
    raise ValueError("no free face")


def cube_fig6_design(subdivisions: int = 3, radius: float = 0.035, cell_radius: float = 0.012,
                     material: Material | None = None) -> Design:
    """The paper's Fig. 6 device: a sphere with five IPAMs, four joining opposite cube-corner
    directions and one joining the centres of two opposite cube faces (+z/-z), with a jamming cell
    around every IPAM end."""
    rest = icosphere(subdivisions, radius)
    d = Design(rest, material)
    c = rest.face_centroids()
    taken: set[int] = set()
    pairs = [(u, -u) for u in corner_directions()] + [(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))]
    for u, w in pairs:
        a = _face_towards(c, u, taken)
        taken.add(a)
        b = _face_towards(c, w, taken)
        taken.add(b)
        d.add_ipam(a, b)
    face_cell = d.face_cell()
    for ip in d.ipams:
        for end in (ip.face_a, ip.face_b):
            near = np.flatnonzero((np.linalg.norm(c - c[end], axis=1) < cell_radius) & (face_cell < 0))
            d.add_cell(near)
            face_cell[near] = d.n_cells - 1
    return d
