"""The fit objective: the scaled radial error, its value, residuals and derivative, in one home.

The fit objective is the area-weighted RMS of the scaled radial error (R - r) / V_t^(1/3) of design
radii r against the target's radii R sampled along the same rays (``sampling.RadialSampler``), the
weights the vertex area shares of the sampled target points (``sampling.vertex_area_shares``). It is
the registered objective ``"scaled_radial"`` (``OBJECTIVES``): ``ScaledRadialError`` holds its per-sample
errors, residual vector (whose norm is the value: the Gauss-Newton steps of the model-based controller),
value per world and per batch; ``fit_objective`` / ``fit_metrics`` check their inputs and give it with
PCC, MARE and MPRE; ``fit_objective_and_gradient`` returns it with dJ/dx, the target faces the rays hit
held fixed (the derivative of the piecewise-smooth objective on the current faces; derivation in
docs/gradients.md, "The objective's derivative").
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError, numeric_array
from ..sampling import FLAT_SPREAD, RadialSampler, paired_radii, vertex_area_shares
from . import OBJECTIVES, Objective

__all__ = ["ScaledRadialError", "SCALED_RADIAL", "fit_objective", "fit_metrics", "fit_objective_and_gradient",
           "area_gradients"]


class ScaledRadialError(Objective):
    """The fit objective: sqrt(sum w e^2 / sum w), e = (R - r) / V_t^(1/3) (unitless)."""

    name = "scaled_radial"
    summary = "area-weighted RMS of the radial error scaled by the target's size, (R - r) / V_t^(1/3)"
    unit = "1"

    def errors(self, r, R, volume):
        return (R - r) / float(volume) ** (1.0 / 3.0)

    def residuals(self, r, R, weights, volume):
        return np.sqrt(weights / weights.sum()) * (R - r) / volume ** (1.0 / 3.0)

    def value(self, r, R, volume, weights=None):
        w = np.ones_like(r) if weights is None else weights
        e = self.errors(r, R, volume)
        return float(np.sqrt(np.sum(w * e * e) / np.sum(w)))

    def values(self, r, R, volumes, weights):
        scale = np.array([float(v) ** (1.0 / 3.0) for v in volumes])[:, None]
        e = (R - r) / scale
        return np.sqrt(np.sum(weights * e * e, axis=1) / np.sum(weights, axis=1))

    def gradient(self, x, sampler, target_index, faces, volume):
        return fit_objective_and_gradient(x, sampler, target_index, faces, volume)


SCALED_RADIAL = OBJECTIVES.register(ScaledRadialError())


def fit_objective(r, R, target_volume: float, weights=None) -> float:
    """The fit objective: the weighted RMS of the scaled radial error (R - r) / V_t^(1/3) (unitless).

    r: design radii, R: sampled target radii (same directions), target_volume: V_t in m^3, weights:
    the area each sample stands for (e.g. the sampled target's vertex areas; None: equal). 0 is a
    perfect fit; 0.01 is a radial error of about 1 % of the target's size. Used by the controller's
    stopping rule, the designer and every report, with PCC, MARE and MPRE beside it.
    """
    r, R = paired_radii(r, R, "objective")
    if not (np.isfinite(target_volume) and target_volume > 0):
        raise ShapeError(f"objective: the target volume must be positive, got {target_volume} m^3")
    w = np.ones_like(r) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != r.shape or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ShapeError(f"objective: weights must be {r.size} finite non-negative numbers, not all zero")
    return SCALED_RADIAL.value(r, R, target_volume, w)


def fit_metrics(r: np.ndarray, R: np.ndarray, target_volumes, weights: np.ndarray) -> dict:
    """Per world the fit of paired radii ``r``, ``R`` (W, N): ``objective`` (``fit_objective`` with
    ``target_volumes`` (W,) m^3 and ``weights`` (W, N)), ``pcc``, ``mare`` (m) and ``mpre`` (%), each a
    (W,) array with the values the single-world functions give (the same arithmetic per row), all
    worlds checked and reduced at once."""
    r = numeric_array(r, "fit: r (radii, m)", ShapeError)
    R = numeric_array(R, "fit: R (radii, m)", ShapeError)
    w = np.asarray(weights, dtype=np.float64)
    if r.ndim != 2 or r.shape != R.shape or w.shape != r.shape or r.shape[1] < 2:
        raise ShapeError(f"fit: r, R and weights must be (W, N) arrays of the same shape with N >= 2, got "
                         f"{r.shape}, {R.shape} and {w.shape}")
    vols = np.asarray(target_volumes, dtype=np.float64).reshape(-1)
    if vols.shape != (r.shape[0],) or not np.all(np.isfinite(vols)) or np.any(vols <= 0):
        raise ShapeError(f"fit: one positive target volume per world needed, got {vols.tolist()} m^3")
    for arr, nm in ((r, "r"), (R, "R")):
        bad = ~np.isfinite(arr)
        if bad.any():
            k = np.argwhere(bad)[0]
            raise ShapeError(f"fit: {nm}[{k[0]}, {k[1]}] is not finite ({int(bad.sum())} non-finite value(s))")
    if not np.all(np.isfinite(w)) or np.any(w < 0) or np.any(w.sum(axis=1) <= 0):
        raise ShapeError("fit: weights must be finite non-negative numbers, not all zero in a world")
    if np.any(R <= 0):
        k = np.argwhere(R <= 0)[0]
        raise ShapeError(f"MPRE: sampled radius R[{k[0]}, {k[1]}] is not positive")
    objective = SCALED_RADIAL.values(r, R, vols, w)
    flat = (np.std(r, axis=1) <= FLAT_SPREAD * np.mean(np.abs(r), axis=1)) | \
        (np.std(R, axis=1) <= FLAT_SPREAD * np.mean(np.abs(R), axis=1))
    dr, dR = r - r.mean(axis=1, keepdims=True), R - R.mean(axis=1, keepdims=True)
    corr = np.array([0.0 if flat[k] else float(np.dot(dr[k], dR[k]) / np.sqrt(float(np.dot(dr[k], dr[k]))
                                                                          * float(np.dot(dR[k], dR[k]))))
                     for k in range(r.shape[0])])
    err = np.abs(r - R)
    return dict(objective=objective, pcc=corr, mare=np.mean(err, axis=1), mpre=100.0 * np.mean(err / R, axis=1))


def area_gradients(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3, 3): d(area of face f)/d(its corner k), for the (V, 3) ``points`` triangulated by ``faces``
    (F, 3): 0.5 n_hat x (p_{k+2} - p_{k+1}), in the face's plane, perpendicular to the opposite edge.
    Zero for a degenerate (zero-area) face."""
    p = points[faces]  # (F, 3, 3)
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    n_hat = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0.0)
    opposite = np.roll(p, -2, axis=1) - np.roll(p, -1, axis=1)  # corner k: p[k+2] - p[k+1]
    return 0.5 * np.cross(n_hat[:, None, :], opposite)


def _check_inputs(x, faces, target_volume):
    x = numeric_array(x, "membrane positions x (m)", ShapeError)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise ShapeError(f"membrane positions x must have shape (V, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ShapeError(f"membrane positions x must be finite; vertex {int(np.flatnonzero(~np.isfinite(x).all(1))[0])} is not")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.size == 0 or not np.issubdtype(faces.dtype, np.integer):
        raise ShapeError(f"faces must be an (F, 3) integer array of vertex indices, got {faces.shape} {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(x):
        raise ShapeError(f"faces index vertices {faces.min()}..{faces.max()}, but x has {len(x)} vertices")
    if not (np.isfinite(target_volume) and target_volume > 0):
        raise ShapeError(f"the target volume must be positive, got {target_volume} m^3")
    r = np.linalg.norm(x, axis=1)
    scale = float(np.max(r))
    at_origin = r <= 1e-12 * max(scale, 1e-300)
    if at_origin.any():
        i = int(np.flatnonzero(at_origin)[0])
        raise ShapeError(f"vertex {i} of the membrane lies at the origin (|x| = {r[i]:.3g} m, {int(at_origin.sum())} "
                         f"such vertex(es)): its ray direction, and so the objective's derivative, is undefined; "
                         f"the membrane must enclose the target's volume centroid with every vertex off it")
    return x, faces.astype(np.int64), r


def fit_objective_and_gradient(x, sampler: RadialSampler, target_index: int, faces,
                               target_volume: float) -> tuple[float, np.ndarray]:
    """The fit objective J of membrane positions ``x`` and its derivative dJ/dx.

    ``x``: (V, 3) vertex positions (m) in the target's frame (origin at its volume centroid);
    ``sampler``: the ``RadialSampler`` holding the target, sampled as target ``target_index``;
    ``faces``: (F, 3) the membrane's faces (they triangulate the sampled points into the weights);
    ``target_volume``: V_t (m^3), the target mesh's own volume.

    Returns ``(J, grad)``: J (unitless) equal to ``controller.observe.fit_of``'s objective for the
    same x (the same sampling, weights and ``fit_objective``), and grad (V, 3) float64, dJ/dx in 1/m.
    The target faces the rays hit come from the sampler's forward pass and are held fixed: grad is the
    derivative of the objective on those faces (it has kinks where a ray crosses a target edge). A ray
    whose hit could not be refined onto its face's plane (nearly parallel to it) keeps R fixed. At a
    perfect fit (J = 0, the RMS's kink) the gradient returned is zero. A vertex at the origin raises
    ``ShapeError``.
    """
    x, faces, r = _check_inputs(x, faces, target_volume)
    hits, hit_faces, on_plane = sampler.sample_worlds_with_faces(x[None], [target_index])
    hits, hit_faces, on_plane = hits[0], hit_faces[0], on_plane[0]
    R = np.linalg.norm(hits, axis=1)
    w = vertex_area_shares(hits[None], faces)[0]
    J = fit_objective(r, R, target_volume, w)
    if J == 0.0:
        return J, np.zeros_like(x)
    scale = float(target_volume) ** (1.0 / 3.0)
    e = SCALED_RADIAL.errors(r, R, target_volume)
    w_sum = float(np.sum(w))
    dJ_dw = (e * e - J * J) / (2.0 * J * w_sum)  # (V,)
    dJ_de = w * e / (J * w_sum)  # (V,)
    # The hit h = off_f x / (n_f . x) on the plane of its face: dR/dx = (R/r)(u - m) and
    # (dh/dx)^T g = (R/r)(g - m (u . g)), m = n_f / (n_f . u); m = u where R is held (off the plane).
    u = x / r[:, None]
    normals, _ = sampler.face_planes(target_index)
    n = normals[hit_faces]
    s = np.einsum("ij,ij->i", n, u)
    m = np.where(on_plane[:, None], n / np.where(on_plane, s, 1.0)[:, None], u)
    ratio = (R / r)[:, None]
    dR_dx = ratio * (u - m)
    grad = (dJ_de / scale)[:, None] * (dR_dx - u)
    # The weights: w_v = sum over v's faces of area_f / 3, the areas of the triangles of hits.
    dJ_darea = dJ_dw[faces].sum(axis=1) / 3.0  # (F,)
    per_corner = dJ_darea[:, None, None] * area_gradients(hits, faces)  # (F, 3, 3)
    dJ_dh = np.stack([np.bincount(faces.reshape(-1), weights=per_corner[..., c].reshape(-1), minlength=len(x))
                      for c in range(3)], axis=1)
    grad += ratio * (dJ_dh - m * np.einsum("ij,ij->i", u, dJ_dh)[:, None])
    return J, grad
