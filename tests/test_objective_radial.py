"""The fit objective's derivative with respect to the membrane's vertices (warp_shape.objectives.radial).

J must be the objective the controller reports (``controller.observe.fit_of``) to rounding, and dJ/dx
must match central finite differences in float64 (step 1e-7 m) on a perturbed icosphere membrane
against shipped targets and generated ones the project does not ship. The derivative holds the hit
target faces fixed, so a finite-difference component whose step moves that vertex's ray onto another
target face is skipped; the check counts them and requires almost none (the random 2 mm perturbations
put no ray within 1e-7 m of a target edge but for a rare few).
"""

from __future__ import annotations

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.controller.observe import fit_of
from warp_shape.errors import ShapeError
from warp_shape.objectives import radial as objective_grad
from warp_shape.objectives.radial import area_gradients, fit_objective_and_gradient
from warp_shape.sampling import RadialSampler

from generated_shapes import shape

NAMES = ("oval", "heart", "egg", "tilted_ellipsoid")
STEP = 1e-7  # m, central finite differences
TOL = 1e-5  # relative, on the gradient's norm and on every component above 1e-3 of the largest


@pytest.fixture(scope="module")
def targets():
    return [ws.target("oval"), ws.target("heart"), shape("egg"), shape("tilted_ellipsoid")]


@pytest.fixture(scope="module")
def sampler(targets):
    return RadialSampler(targets, names=list(NAMES))


def membrane(seed: int, radius: float = 0.04, noise: float = 0.002):
    """An icosphere(2) membrane (162 vertices) with every vertex moved randomly by ~``noise`` m."""
    mesh = ws.icosphere(2, radius)
    x = mesh.vertices + np.random.default_rng(seed).normal(scale=noise, size=mesh.vertices.shape)
    return x, mesh.faces


def reported_objective(x, sampler, index, faces, volume) -> float:
    sampled = sampler.sample_worlds(x[None], [index])
    return float(fit_of(x[None], sampled, faces, np.array([volume]))["objective"][0])


@pytest.mark.parametrize("index", range(len(NAMES)), ids=NAMES)
@pytest.mark.parametrize("radius", [0.04, 0.025], ids=["outside", "inside"])
def test_objective_is_the_reported_one(sampler, targets, index, radius):
    x, faces = membrane(seed=10 + index, radius=radius)
    J, grad = fit_objective_and_gradient(x, sampler, index, faces, targets[index].volume())
    assert J == pytest.approx(reported_objective(x, sampler, index, faces, targets[index].volume()), rel=1e-12)
    assert J > 0.01 and grad.shape == x.shape and np.all(np.isfinite(grad))


def finite_differences(x, sampler, index, faces, volume):
    """(V, 3) central differences of the reported objective, and (V, 3) bool: True where the step
    changed the target face that vertex's ray hits (the derivative there is not of the same piece)."""
    V = len(x)
    worlds = np.repeat(x[None], 6 * V, axis=0)  # world 2k: component k stepped +, world 2k+1: stepped -
    k = np.arange(3 * V)
    worlds[2 * k, k // 3, k % 3] += STEP
    worlds[2 * k + 1, k // 3, k % 3] -= STEP
    hits, hit_faces, _ = sampler.sample_worlds_with_faces(worlds, [index] * len(worlds))
    J = fit_of(worlds, hits, faces, np.full(len(worlds), volume))["objective"]
    _, base_faces, _ = sampler.sample_worlds_with_faces(x[None], [index])
    own = hit_faces[np.arange(6 * V), np.repeat(k // 3, 2)]  # the stepped vertex's face in each world
    changed = (own != np.repeat(base_faces[0, k // 3], 2)).reshape(3 * V, 2).any(axis=1).reshape(V, 3)
    return ((J[0::2] - J[1::2]) / (2.0 * STEP)).reshape(V, 3), changed


@pytest.mark.parametrize("index", range(len(NAMES)), ids=NAMES)
def test_gradient_matches_central_differences(sampler, targets, index):
    x, faces = membrane(seed=index)
    volume = targets[index].volume()
    _, grad = fit_objective_and_gradient(x, sampler, index, faces, volume)
    fd, changed = finite_differences(x, sampler, index, faces, volume)
    assert changed.sum() <= 3, f"{changed.sum()} steps changed a hit face: pick another perturbation"
    keep = ~changed
    assert np.linalg.norm((grad - fd)[keep]) <= TOL * np.linalg.norm(grad[keep])
    big = keep & (np.abs(grad) > 1e-3 * np.abs(grad).max())
    assert big.sum() > 0.8 * grad.size
    rel = np.abs(grad - fd)[big] / np.abs(grad[big])
    assert rel.max() <= TOL, f"worst component off by {rel.max():.2e} relative"


def test_the_weights_move_with_the_hits(sampler, targets, monkeypatch):
    """The area weights' dependence on x is a large part of the gradient (a quarter of its norm on the
    oval): dropping it would fail the finite-difference check by far more than its tolerance."""
    x, faces = membrane(seed=0)
    _, grad = fit_objective_and_gradient(x, sampler, 0, faces, targets[0].volume())
    fd, changed = finite_differences(x, sampler, 0, faces, targets[0].volume())
    monkeypatch.setattr(objective_grad, "area_gradients", lambda points, f: np.zeros((len(f), 3, 3)))
    _, weights_free = fit_objective_and_gradient(x, sampler, 0, faces, targets[0].volume())
    keep = ~changed
    assert np.linalg.norm((weights_free - fd)[keep]) > 100 * TOL * np.linalg.norm(fd[keep])
    assert np.linalg.norm((grad - fd)[keep]) < TOL * np.linalg.norm(fd[keep])


def test_area_gradients_match_differences():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(3, 3))
    faces = np.array([[0, 1, 2]])
    g = area_gradients(points, faces)[0]

    def area(p):
        return 0.5 * np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))

    for k in range(3):
        for c in range(3):
            d = np.zeros((3, 3))
            d[k, c] = 1e-6
            assert g[k, c] == pytest.approx((area(points + d) - area(points - d)) / 2e-6, rel=1e-7, abs=1e-12)


def test_vertex_at_the_origin_is_refused(sampler, targets):
    x, faces = membrane(seed=0)
    x[17] = 0.0
    with pytest.raises(ShapeError, match="vertex 17 of the membrane lies at the origin"):
        fit_objective_and_gradient(x, sampler, 0, faces, targets[0].volume())
