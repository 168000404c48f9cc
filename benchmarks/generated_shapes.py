"""Target shapes the project does not ship, generated for the tests and the co-design benchmark: an egg, a tilted triaxial ellipsoid,
a rounded puck, a peanut with a waist, a bean and a teardrop.

Each is a radial function r(u) of the unit direction u, sampled on an icosphere's vertices, so every
shape is star-shaped from the origin by construction; ``shape(name)`` returns it scaled to the shipped
targets' volume and centred on its volume centroid.
"""

from __future__ import annotations

import numpy as np

import warp_shape as ws

NAMES = ("egg", "tilted_ellipsoid", "puck", "peanut", "bean", "teardrop")


def _rotation(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a /= np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _ellipsoid_radius(u: np.ndarray, axes) -> np.ndarray:
    return 1.0 / np.sqrt(np.sum((u / np.asarray(axes)) ** 2, axis=1))


def _radius(name: str, u: np.ndarray) -> np.ndarray:
    x, y, z = u.T
    if name == "egg":  # longer than wide, blunt end down
        return _ellipsoid_radius(u, (0.8, 0.8, 1.05)) * (1.0 - 0.12 * z)
    if name == "tilted_ellipsoid":  # three different axes, turned off every coordinate axis
        return _ellipsoid_radius(u @ _rotation((1.0, 2.0, 0.5), 0.7), (1.15, 0.85, 0.65))
    if name == "puck":  # a rounded disc: superellipse profile, flat top and bottom
        rho = np.sqrt(x * x + y * y)
        return (rho**4 / 1.0**4 + np.abs(z) ** 4 / 0.45**4) ** -0.25
    if name == "peanut":  # two lobes along x with a waist between them
        return 0.75 + 0.35 * x * x - 0.12 * (y * y + z * z) * (1 - x * x)
    if name == "bean":  # a kidney: an ellipsoid bent around z, dented on one side
        base = _ellipsoid_radius(u, (1.2, 0.7, 0.75))
        return base * (1.0 - 0.22 * np.exp(-((y - 0.9) ** 2 + z * z) / 0.3))
    if name == "teardrop":  # round at the bottom, narrowing to a blunt tip at the top
        return 0.7 * (1.0 + 0.55 * np.clip(z, 0, None) ** 2) * (1.0 - 0.1 * z)
    raise ValueError(f"unknown generated shape {name!r}; choose one of {NAMES}")


def shape(name: str, volume: float = ws.DEFAULT_VOLUME, subdivisions: int = 4) -> ws.TriMesh:
    """The generated shape ``name`` with volume ``volume`` (m^3), centred on its volume centroid."""
    sphere = ws.icosphere(subdivisions, 1.0)
    u = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    mesh = ws.TriMesh(u * _radius(name, u)[:, None], sphere.faces).centered()
    return mesh.scaled((volume / mesh.volume()) ** (1.0 / 3.0))
