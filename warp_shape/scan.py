"""Comparison of a 3-D scan with a reference shape (section V-D).

The paper scanned the inflated display (Kinect Fusion), aligned the scan roughly to the model,
refined the alignment by ICP and compared the two by radial sampling. ``compare_scan`` does the same:

1. **Load.** The scan may be open, partial, noisy or a bare point cloud (PLY/STL/OBJ/GLB, any
   format trimesh reads); it is not validated as a closed mesh, only its points are used, weighted
   by their share of the scan's triangle area when it has triangles. The reference (a design's
   achieved shape or a target) must be a closed star-shaped mesh; it is centred on its volume
   centroid.
2. **Rough alignment.** The area-weighted centroids and principal axes of scan and reference
   surface are matched. The axes are only defined up to order and sign (and a partial scan skews
   them), so all 24 proper signed axis permutations, plus the scan's own pose, are each refined by
   a few ICP iterations on a subset and the one with the lowest trimmed RMS distance is kept.
3. **ICP.** Point-to-surface ICP: the closest point on the reference of every scan point comes from
   the Warp BVH (``wp.mesh_query_point_no_sign``); the rigid update is a shortened point-to-plane
   Gauss-Newton step when it lowers the error, else the weighted Kabsch (SVD) fit (see ``icp``).
   Outliers are trimmed every iteration: pairs farther than ``inlier_sigmas`` robust standard
   deviations (1.4826 * median distance) are ignored, so scans that miss part of the surface or
   carry extra geometry (a table, tubing) still align. Scan -> reference is the right direction for
   a partial scan: every scan point has a true partner on the complete reference.
4. **Metrics.** Radial sampling of the reference through the aligned inlier scan points (the scan
   plays the design mesh's role of section IV-A): r = |scan point|, R = |hit of the ray through it
   on the reference|, both from the reference centroid; PCC, MARE, MPRE as in ``sampling``.
5. **Coverage.** The share of the reference surface within a distance of the scan, for meshes and
   point clouds alike, measured at ``COVERAGE_SAMPLES`` area-uniform points on the reference. The
   distance is to the aligned scan surface (meshes) or to the nearest inlier scan point (point
   clouds); the radius is 3 rms (+0.1 % of the size) for meshes, and 3 point spacings (median
   nearest-neighbour distance) + 3 rms for point clouds, so the gaps between points count as
   covered. The set within the radius is then eroded by the radius (a morphological closing), so
   it does not reach past the scan's edge; a point cloud's edge is then moved out by the part of
   the surface its outermost points stand for (``_edge_margin``: half a spacing on a regular grid,
   a whole one for random points). ``uncovered_direction`` is the mean direction (from the
   reference centroid, reference frame) of the uncovered surface. A one-sided scan of 60 % of a
   sphere measures 60 +- 1 % from 370 to 12000 points, grid-like or random, and as a mesh.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import warp as wp

from .errors import MeshError, ShapeError, check_input_file, check_number, check_whole
from .kernels import raycast
from .mesh import TriMesh, regular_file_resolver
from .sampling import RadialSampler, radial_metrics
from .targets import TARGET_NAMES, target

__all__ = ["ScanComparison", "JSON_KEYS", "IcpConvergenceWarning", "compare_scan", "surface_samples", "load_scan", "icp", "kabsch",
           "surface_distances", "closest_points_query", "detect_length_unit", "length_unit_of", "LENGTH_UNITS", "PLAUSIBLE_EXTENT_M"]

# Ignore pairs farther than this many robust standard deviations of the pair distances.
INLIER_SIGMAS = 3.0
# Points used by ICP and by the rough-alignment trials (a deterministic subset of the scan).
ICP_POINTS = 4000
TRIAL_POINTS = 800
TRIAL_ITERATIONS = 8
# Area-uniform points on the reference at which coverage is measured.
COVERAGE_SAMPLES = 40000
# Longest point-to-plane step of ICP: rotation (rad), and shift as a fraction of the size.
_PLANE_STEP_MAX = 0.05
#: Length units a scan or reference file may be in -> factor to metres ("auto": ``detect_length_unit``).
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
#: Largest extent (m) of a plausible shape display or a scan of one; a file whose numbers fit this
#: range read as metres is in metres, one whose numbers fit it read as millimetres in millimetres.
PLAUSIBLE_EXTENT_M = (0.02, 2.0)


#: ``ScanComparison`` field -> its key in ``to_dict`` (and ``compare --json``): the unit in the name
JSON_KEYS = {"transform": "transform_m", "mare": "mare_m", "mpre": "mpre_pct", "rms": "rms_m",
             "last_move": "last_move_m", "coverage_radius": "coverage_radius_m",
             "reference_centroid": "reference_centroid_m"}


class IcpConvergenceWarning(UserWarning):
    """ICP stopped at its iteration limit before its tolerance was met."""


@dataclass
class ScanComparison:
    """Result of ``compare_scan``. Lengths in metres, MPRE in percent.

    ``transform``: 4x4 rigid transform taking scan coordinates to reference coordinates.
    ``rms``: RMS distance of the inlier scan points to the reference surface after ICP.
    ``covered_fraction``: share of the reference's surface area the scan covers.
    ``uncovered_direction``: unit direction (reference frame, from its centroid) of the area-weighted
    mean of the uncovered surface, or None when everything is covered.
    ``converged``: ICP met its tolerance before its iteration limit (else an ``IcpConvergenceWarning``
    was issued); ``last_move``: the last ICP update's largest point displacement.
    ``coverage_radius``: the distance within which the scan covers the reference (step 5).
    ``scan_units`` / ``reference_units``: the unit each input's numbers were read in ("m" or "mm"),
    every length of the result is in metres whatever they were.
    """

    transform: np.ndarray
    pcc: float
    mare: float
    mpre: float
    covered_fraction: float
    rms: float
    iterations: int
    uncovered_direction: np.ndarray | None
    n_points: int = 0
    n_inliers: int = 0
    converged: bool = True
    last_move: float = 0.0
    coverage_radius: float = 0.0
    reference_centroid: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scan_units: str = "m"
    reference_units: str = "m"

    def to_dict(self) -> dict:
        """The comparison as a JSON-ready dict, every key that carries a unit named with it (``JSON_KEYS``:
        ``mare_m``, ``rms_m``, ``mpre_pct``, ``transform_m`` (its translation in m) ...)."""
        d = {}
        for k, v in asdict(self).items():
            d[JSON_KEYS.get(k, k)] = v.tolist() if isinstance(v, np.ndarray) else v
        return d


# ---------------------------------------------------------------------------------------- loading
def load_scan(scan) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (N, 3) float64 and triangles (F, 3) int (or None) of a scan, without closing checks.

    ``scan``: a TriMesh, a trimesh object, an (N, 3) array, a ``(vertices, faces)`` pair, or a path
    of any format trimesh reads (scenes are concatenated, point clouds keep no faces).
    """
    if isinstance(scan, TriMesh):
        return scan.vertices.copy(), scan.faces.copy()
    if isinstance(scan, (str, Path)):
        path = Path(scan)
        check_input_file(path, "scan file", ShapeError)
        import trimesh

        try:
            scan = trimesh.load(str(path), resolver=regular_file_resolver(path))
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ShapeError(f"could not read scan {path}: {exc}") from exc
    if hasattr(scan, "geometry") and isinstance(getattr(scan, "geometry"), dict):  # trimesh.Scene
        parts = list(scan.dump()) if hasattr(scan, "dump") else list(scan.geometry.values())
        verts, faces, off = [], [], 0
        for g in parts:
            verts.append(np.asarray(g.vertices, dtype=np.float64))
            if getattr(g, "faces", None) is not None and len(g.faces):
                faces.append(np.asarray(g.faces) + off)
            off += len(g.vertices)
        if not verts:
            raise ShapeError("scan scene holds no geometry")
        return np.concatenate(verts), (np.concatenate(faces) if faces else None)
    if hasattr(scan, "vertices"):
        f = getattr(scan, "faces", None)
        f = None if f is None or len(f) == 0 else np.asarray(f, dtype=np.int64)
        return np.asarray(scan.vertices, dtype=np.float64), f
    if isinstance(scan, tuple) and len(scan) == 2:
        return np.asarray(scan[0], dtype=np.float64), np.asarray(scan[1], dtype=np.int64)
    arr = np.asarray(scan, dtype=np.float64)
    if arr.ndim == 2 and arr.shape[1] == 3:
        return arr, None
    raise ShapeError(f"cannot read a scan from {type(scan).__name__}")


def detect_length_unit(points, what: str = "scan") -> str:
    """``"m"`` or ``"mm"``: the unit in which ``points`` (N, 3) span a plausible shape display
    (``PLAUSIBLE_EXTENT_M``, largest extent). Raises ``ShapeError`` where neither fits."""
    ext = float(np.max(np.ptp(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0)))
    lo, hi = PLAUSIBLE_EXTENT_M
    for unit, factor in LENGTH_UNITS.items():
        if lo <= ext * factor <= hi:
            return unit
    raise ShapeError(f"{what} is {ext:.4g} units across: neither metres nor millimetres give a display "
                     f"{lo * 1e3:g} mm to {hi:g} m across"
                     f"{_centimetres(ext) or '; scale the file to metres or millimetres'}")


def length_unit_of(points, units: str, what: str) -> str:
    """The unit ``points`` are read in: ``units`` ("m" or "mm", checked to give a plausible display,
    ``PLAUSIBLE_EXTENT_M``), or for ``"auto"`` the one detected (``detect_length_unit``)."""
    if units == "auto":
        return detect_length_unit(points, what)
    if units not in LENGTH_UNITS:
        raise ShapeError(f"{what} units must be one of {', '.join([*LENGTH_UNITS, 'auto'])}, got {units!r}")
    ext = float(np.max(np.ptp(points, axis=0))) * LENGTH_UNITS[units]
    if not PLAUSIBLE_EXTENT_M[0] <= ext <= PLAUSIBLE_EXTENT_M[1]:
        other = next(u for u in LENGTH_UNITS if u != units)
        raw = ext / LENGTH_UNITS[units]  # the file's own numbers: the other unit first, then centimetres
        if PLAUSIBLE_EXTENT_M[0] <= raw * LENGTH_UNITS[other] <= PLAUSIBLE_EXTENT_M[1]:
            guess = f"; is it in {other}? (--units {other} or auto)"
        else:
            guess = _centimetres(raw) or "; nor in m or mm: scale the file to metres or millimetres"
        raise ShapeError(f"{what} is {ext:.4g} m across read in {units}: no shape display is{guess}")
    return units


def _centimetres(ext: float) -> str:
    """The hint for a file ``ext`` units across that is a plausible display in centimetres (cm read as m is
    100x too big), or ''."""
    if not PLAUSIBLE_EXTENT_M[0] <= ext * 1e-2 <= PLAUSIBLE_EXTENT_M[1]:
        return ""
    return (f"; it looks like centimetres ({ext:.4g} cm across), which --units does not read: save the file in "
            f"metres or millimetres and give --units m or --units mm")


def _load_reference(reference) -> TriMesh:
    if isinstance(reference, TriMesh):
        return reference
    if isinstance(reference, str) and not Path(reference).exists():
        if reference.strip().lower() in TARGET_NAMES:
            return target(reference)
        raise ShapeError(f"reference {reference!r} is neither a mesh file nor a target "
                         f"({', '.join(TARGET_NAMES)})")
    try:
        return TriMesh.load(reference)
    except MeshError as exc:
        raise ShapeError(f"reference must be a closed mesh: {exc}") from None


def _point_weights(points: np.ndarray, faces: np.ndarray | None) -> np.ndarray:
    """Area share of each point (uniform for point clouds), normalised to mean 1."""
    if faces is None or len(faces) == 0:
        return np.ones(len(points))
    v = points[faces]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    w = np.zeros(len(points))
    np.add.at(w, faces.reshape(-1), np.repeat(area / 3.0, 3))
    if w.sum() <= 0:
        return np.ones(len(points))
    # points in no triangle (stray vertices) get the smallest positive weight, not zero
    pos = w[w > 0]
    w[w <= 0] = pos.min()
    return w / w.mean()


# ---------------------------------------------------------------------------------------- rigid fit
def kabsch(x: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising sum w |R x + t - y|^2 (weighted Kabsch, SVD)."""
    w = np.ones(len(x)) if w is None else np.asarray(w, dtype=np.float64)
    ws = w / w.sum()
    mx, my = ws @ x, ws @ y
    h = (x - mx).T @ ((y - my) * ws[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, my - r @ mx


class _Closest:
    """Closest points on a mesh for batches of query points (device buffers reused)."""

    def __init__(self, mesh, device):
        vertices, faces = load_scan(mesh)
        if faces is None or len(faces) == 0:
            raise ShapeError("closest-point queries need a mesh with triangles, got a point cloud")
        self._k = raycast.closest_points_kernel
        self.device = device
        self._mesh = wp.Mesh(points=wp.array(vertices.astype(np.float32), dtype=wp.vec3, device=device),
                             indices=wp.array(faces.reshape(-1).astype(np.int32), dtype=wp.int32, device=device))
        self.max_dist = 1e3 * float(np.max(np.linalg.norm(vertices, axis=1)) + np.max(np.ptp(vertices, axis=0)))

    def __call__(self, points: np.ndarray, normals: bool = False):
        """Closest points (N, 3) and distances (N,), plus face normals (N, 3) if ``normals``."""
        n = len(points)
        dev = self.device
        p = wp.array(points.astype(np.float32), dtype=wp.vec3, device=dev)
        c = wp.empty(n, dtype=wp.vec3, device=dev)
        nrm = wp.empty(n, dtype=wp.vec3, device=dev)
        d = wp.empty(n, dtype=wp.float32, device=dev)
        wp.launch(self._k, dim=n, inputs=[self._mesh.id, self.max_dist, p], outputs=[c, nrm, d], device=dev)
        c, d = c.numpy().astype(np.float64), d.numpy()
        if np.any(d < 0):
            raise ShapeError("closest-point query found no surface near some scan points")
        # float64 distance from the float32 closest point
        d = np.linalg.norm(c - points, axis=1)
        return (c, d, nrm.numpy().astype(np.float64)) if normals else (c, d)


def closest_points_query(mesh, *, device=None):
    """A query of the closest points on ``mesh`` (a TriMesh, trimesh object or ``(vertices, faces)``; open
    meshes allowed) on the Warp BVH, as ``icp`` takes it: ``query(points)`` gives (closest points (N, 3),
    distances (N,)), ``query(points, normals=True)`` also the closest faces' unit normals (N, 3)."""
    return _Closest(mesh, wp.get_device(device))


def surface_distances(points, mesh, *, device=None) -> np.ndarray:
    """Unsigned distance (N,) from each point to the surface of ``mesh`` (a TriMesh, trimesh object
    or ``(vertices, faces)``; open meshes allowed), in the points' units, on the Warp BVH."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return _Closest(mesh, wp.get_device(device))(pts)[1]


def _inliers(d: np.ndarray, sigmas: float, floor: float) -> np.ndarray:
    return d <= max(sigmas * 1.4826 * float(np.median(d)), floor)


def _rotation(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``omega`` (Rodrigues)."""
    a = float(np.linalg.norm(omega))
    if a < 1e-15:
        return np.eye(3)
    k = np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]]) / a
    return np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * (k @ k)


def _point_to_plane(x, q, n, w, max_angle: float, max_shift: float):
    """Rigid update (dr, dt) minimising sum w ((dr x + dt - q) . n)^2, linearised (one Gauss-Newton
    step) and shortened to at most ``max_angle`` rad and ``max_shift`` m. Solved about the centroid
    of x for conditioning; least squares keeps it finite when a symmetry of the surface leaves a
    direction free."""
    c = np.average(x, axis=0, weights=w)
    xc = x - c
    jac = np.concatenate([np.cross(xc, n), n], axis=1)  # (N, 6): d residual / d (omega, delta)
    res = np.einsum("ij,ij->i", x - q, n)
    sw = np.sqrt(w)[:, None]
    xi = np.linalg.lstsq(jac * sw, -res * sw[:, 0], rcond=None)[0]
    xi *= min(1.0, max_angle / max(np.linalg.norm(xi[:3]), 1e-300), max_shift / max(np.linalg.norm(xi[3:]), 1e-300))
    dr = _rotation(xi[:3])
    return dr, c + xi[3:] - dr @ c


def icp(points: np.ndarray, closest: _Closest, r: np.ndarray, t: np.ndarray, *, weights=None,
        max_iterations: int = 200, tolerance: float = 1e-5, inlier_sigmas: float = INLIER_SIGMAS,
        scale: float = 1.0, method: str = "point_to_plane", info: dict | None = None):
    """Trimmed ICP of ``points`` onto the reference surface from the pose (r, t).

    Every iteration pairs each point with its closest point on the surface and drops the outlier
    pairs. ``method="point_to_point"``: the update is the weighted Kabsch fit of the inliers to
    their partners: robust from far away, but slow to slide along smooth surfaces.
    ``"point_to_plane"`` (default): a Gauss-Newton step on the distances to the partners' tangent
    planes, shortened to ``_PLANE_STEP_MAX`` (rad, and that fraction of ``scale`` in metres) and
    taken only if it lowers the truncated RMS, else the Kabsch step; it slides along flat valleys
    of near-symmetric shapes and finishes in a few iterations once close. Stops when an
    update moves no point by more than ``tolerance * scale``. Returns (r, t, rms, iterations), rms
    over the inliers. ``info`` (a dict), when given, receives ``converged`` (the tolerance was met
    before ``max_iterations``) and ``last_move`` (m, the last update's largest point displacement).
    """
    if method not in ("point_to_plane", "point_to_point"):
        raise ShapeError(f"ICP method must be 'point_to_plane' or 'point_to_point', got {method!r}")
    w = np.ones(len(points)) if weights is None else weights
    rms = np.inf
    it = 0
    move = np.inf
    cached = None
    for it in range(1, max_iterations + 1):
        x = points @ r.T + t
        q, d, n = cached if cached is not None else closest(x, normals=True)
        cached = None
        keep = _inliers(d, inlier_sigmas, 1e-9 * scale)
        cap = float(d[keep].max())
        rms = float(np.sqrt(np.average(d[keep] ** 2, weights=w[keep])))
        step = None
        if method == "point_to_plane":
            dr, dt = _point_to_plane(x[keep], q[keep], n[keep], w[keep], _PLANE_STEP_MAX,
                                     _PLANE_STEP_MAX * scale)
            trial = closest(x @ dr.T + dt, normals=True)
            # truncated quadratic with this iteration's cap: fair to both poses
            before = np.average(np.minimum(d, cap) ** 2, weights=w)
            after = np.average(np.minimum(trial[1], cap) ** 2, weights=w)
            if after <= before:
                step, cached = (dr, dt), trial
        if step is None:
            step = kabsch(x[keep], q[keep], w[keep])
        dr, dt = step
        r, t = dr @ r, dr @ t + dt
        # largest displacement of a point of the set by this update
        move = float(np.max(np.linalg.norm(x @ (dr - np.eye(3)).T + dt, axis=1)))
        if move < tolerance * scale:
            break
    if info is not None:
        info.update(converged=bool(move < tolerance * scale), last_move=move)
    return r, t, rms, it


def _trimmed_rms(d: np.ndarray, keep: float = 0.8) -> float:
    s = np.sort(d)
    return float(np.sqrt(np.mean(s[: max(1, int(keep * len(s)))] ** 2)))


def _surface_moments(points: np.ndarray, w: np.ndarray):
    ws = w / w.sum()
    mu = ws @ points
    cov = ((points - mu) * ws[:, None]).T @ (points - mu)
    _, axes = np.linalg.eigh(cov)  # columns, ascending variance
    return mu, axes


def _candidate_rotations(ax_scan: np.ndarray, ax_ref: np.ndarray) -> list[np.ndarray]:
    """Identity plus the 24 rotations mapping the scan's principal axes onto the reference's."""
    out = [np.eye(3)]
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[np.arange(3), perm] = signs
            r = ax_ref @ m @ ax_scan.T
            if np.linalg.det(r) > 0:
                out.append(r)
    return out


# ---------------------------------------------------------------------------------------- coverage
def _nearest_distances(points: np.ndarray, queries: np.ndarray, radius: float, device,
                       skip_self: bool) -> np.ndarray:
    """Distance from each query to the nearest of ``points`` (-1 beyond ``radius``), on a hash grid."""
    grid = wp.HashGrid(64, 64, 64, device=device)
    p = wp.array(points.astype(np.float32), dtype=wp.vec3, device=device)
    grid.build(p, radius)
    q = p if skip_self else wp.array(queries.astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.empty(len(queries), dtype=wp.float32, device=device)
    wp.launch(raycast.nearest_point_distance_kernel, dim=len(queries),
              inputs=[grid.id, float(radius), int(skip_self), p, q], outputs=[out], device=device)
    return out.numpy().astype(np.float64)


def surface_samples(mesh: TriMesh, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) points spread uniformly by area over a mesh's surface (random, seeded)."""
    rng = np.random.default_rng(seed)
    area = mesh.face_areas()
    f = rng.choice(mesh.n_faces, size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    tri = mesh.vertices[mesh.faces[f]]
    return tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])


def _closing(samples: np.ndarray, near: np.ndarray, radius: float, device) -> np.ndarray:
    """Erode the set ``near`` (samples within ``radius`` of the scan) by ``radius``: keeps the
    samples whose nearest sample outside the set is farther than ``radius``. Dilation then erosion
    (a closing) fills gaps between scan points but does not reach past the scan's edge."""
    if near.all() or not near.any():
        return near.copy()
    d = _nearest_distances(samples[~near], samples[near], radius, device, skip_self=False)
    out = near.copy()
    out[near] = d < 0
    return out


def _edge_margin(area: float, n_points: int, spacing: float) -> float:
    """How far past its outermost points a point cloud's surface reaches: ``beta`` x the area
    spacing a = sqrt(area / points). A regular grid's edge lies half a spacing beyond its last row
    (beta 0.5); random points stop short of the edge by about another half spacing (beta 1). The
    ratio of the median nearest-neighbour distance to a tells them apart (1.07 on a hexagonal grid,
    0.47 for random points), and beta is interpolated between."""
    a = np.sqrt(area / max(n_points, 1))
    if not a > 0:
        return 0.0
    beta = float(np.interp(spacing / a, [0.47, 1.0], [1.0, 0.5]))
    return beta * a


def _coverage(ref: TriMesh, aligned: np.ndarray, faces: np.ndarray | None, keep: np.ndarray, rms: float,
              device, samples: int = COVERAGE_SAMPLES) -> tuple[float, np.ndarray | None, dict]:
    """Covered share of the reference area, the mean direction of the uncovered part and how it
    was measured (module docstring, step 5)."""
    q = surface_samples(ref, samples, seed=1)
    size = float(np.max(np.linalg.norm(ref.vertices, axis=1)))
    how = {"samples": samples}
    if faces is not None and len(faces):
        radius = 3.0 * rms + 1e-3 * size
        near = _Closest((aligned, faces), device)(q)[1] <= radius
        covered = _closing(q, near, radius, device)
    else:
        pts = aligned[keep]
        guess = 4.0 * np.sqrt(float(ref.face_areas().sum()) / max(len(pts), 1))
        nn = _nearest_distances(pts, pts, guess, device, skip_self=True)
        spacing = float(np.median(nn[nn >= 0])) if np.any(nn >= 0) else guess
        radius = 3.0 * spacing + 3.0 * rms
        near = _nearest_distances(pts, q, radius, device, skip_self=False) >= 0
        closed = _closing(q, near, radius, device)
        margin = _edge_margin(float(ref.face_areas().sum()) * closed.mean(), len(pts), spacing)
        covered = closed if margin <= 0 or not closed.any() else \
            _nearest_distances(q[closed], q, margin, device, skip_self=False) >= 0
        how.update(spacing=spacing, edge_margin=float(margin))
    how["radius"] = float(radius)
    frac = float(covered.mean())
    if covered.all():
        return frac, None, how
    u = q[~covered] / np.linalg.norm(q[~covered], axis=1, keepdims=True)
    m = u.sum(axis=0)
    n = np.linalg.norm(m)
    return frac, (m / n if n > 0 else None), how


# ---------------------------------------------------------------------------------------- main entry
#: a scan whose points spread across their main axis less than this fraction of along it lies on a line
MIN_SCAN_SPREAD = 1e-3


def check_scan_spread(pts: np.ndarray) -> None:
    """A clear ``ShapeError`` for a degenerate scan whose points lie on one line (coincident points are
    refused by the size check of ``length_unit_of``): such a scan fits anything, ICP converges on nothing."""
    spread = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False) / np.sqrt(len(pts))  # rms along the axes
    if spread[1] < MIN_SCAN_SPREAD * spread[0]:
        raise ShapeError(f"the scan's {len(pts)} points lie on one line (spread {spread[0]:.3g} m along it, "
                         f"{spread[1]:.3g} m across): a degenerate scan; give the scanned surface's points")


def _check_icp_settings(max_iterations, tolerance, inlier_sigmas) -> None:
    """The alignment's settings: a whole number of iterations >= 1, a finite tolerance and inlier width
    > 0 (a NaN tolerance is never met: the alignment ran to its limit and said so nowhere)."""
    if check_whole(max_iterations, "max_iterations", ShapeError) < 1:
        raise ShapeError(f"max_iterations must be at least 1, got {max_iterations}")
    for name, value in (("tolerance", tolerance), ("inlier_sigmas", inlier_sigmas)):
        if not check_number(value, name, ShapeError) > 0:
            raise ShapeError(f"{name} must be a finite number > 0, got {value!r}")


def compare_scan(scan, reference, *, device=None, max_iterations: int = 200, tolerance: float = 1e-5,
                 method: str = "point_to_plane",
                 inlier_sigmas: float = INLIER_SIGMAS, icp_points: int = ICP_POINTS,
                 initial_transform: np.ndarray | None = None, seed: int = 0, scan_units: str = "m",
                 reference_units: str = "m") -> ScanComparison:
    """Align ``scan`` to ``reference`` and measure the fit (section V-D); see the module docstring.

    ``scan``: TriMesh, path (any trimesh format; open or partial meshes and point clouds accepted),
    trimesh object or (N, 3) points. ``reference``: closed TriMesh, mesh path or target name.
    ``scan_units`` / ``reference_units``: "m", "mm" or "auto" (``detect_length_unit``), the unit of
    the numbers in each (a shipped target is always in metres); either, read in its unit, must span
    a plausible display (``PLAUSIBLE_EXTENT_M``), else ``ShapeError`` names the other unit.
    ``initial_transform`` (4x4, scan -> reference, metres) skips the rough alignment."""
    _check_icp_settings(max_iterations, tolerance, inlier_sigmas)
    device = wp.get_device(device)
    pts, faces = load_scan(scan)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 10:
        raise ShapeError(f"scan needs at least 10 points of 3 coordinates, got shape {pts.shape}")
    finite = np.all(np.isfinite(pts), axis=1)
    if not finite.all():
        raise ShapeError(f"scan point {int(np.flatnonzero(~finite)[0])} is not finite")
    ref = _load_reference(reference)
    scan_units = length_unit_of(pts, scan_units, "the scan")
    shipped = isinstance(reference, str) and not Path(reference).exists()
    reference_units = "m" if shipped else length_unit_of(ref.vertices, reference_units, "the reference")
    pts = pts * LENGTH_UNITS[scan_units]
    ref = ref.scaled(LENGTH_UNITS[reference_units]) if reference_units != "m" else ref
    c_ref = ref.centroid()
    refc = ref.centered()
    scale = float(np.max(np.linalg.norm(refc.vertices, axis=1)))
    check_scan_spread(pts)
    sampler = RadialSampler(refc, device=device, names=["reference"])  # checks star shape
    closest = _Closest(refc, device)
    w = _point_weights(pts, faces)

    rng = np.random.default_rng(seed)
    sub = rng.choice(len(pts), size=min(icp_points, len(pts)), replace=False)
    trial = sub[: min(TRIAL_POINTS, len(sub))]

    if initial_transform is not None:
        tf = np.asarray(initial_transform, dtype=np.float64)
        r0, t0 = tf[:3, :3], tf[:3, 3] - c_ref
    else:
        # rough alignment: centroids and principal axes of the two surfaces
        mu_s, ax_s = _surface_moments(pts, w)
        mu_r, ax_r = _surface_moments(refc.face_centroids(), refc.face_areas())
        best = None
        for r in _candidate_rotations(ax_s, ax_r):
            r1, t1, _, _ = icp(pts[trial], closest, r, mu_r - r @ mu_s, weights=w[trial],
                               max_iterations=TRIAL_ITERATIONS, tolerance=tolerance,
                               inlier_sigmas=inlier_sigmas, scale=scale, method="point_to_point")
            score = _trimmed_rms(closest(pts[trial] @ r1.T + t1)[1])
            if best is None or score < best[0]:
                best = (score, r1, t1)
        _, r0, t0 = best
    info = {}
    r, t, rms, iters = icp(pts[sub], closest, r0, t0, weights=w[sub], max_iterations=max_iterations,
                           tolerance=tolerance, inlier_sigmas=inlier_sigmas, scale=scale, method=method, info=info)
    if not info["converged"]:
        warnings.warn(f"ICP ({method}) did not converge in {iters} iterations: residual rms {rms * 1e3:.3f} mm, "
                      f"last update moved points by {info['last_move'] * 1e3:.4f} mm (tolerance "
                      f"{tolerance * scale * 1e3:.4f} mm); the alignment may be off: raise --max-iterations"
                      f"{' or use --method point_to_plane' if method == 'point_to_point' else ''}",
                      IcpConvergenceWarning, stacklevel=2)

    aligned = pts @ r.T + t
    proj, d = closest(aligned)
    keep = _inliers(d, inlier_sigmas, 1e-9 * scale)
    metrics = radial_metrics(np.linalg.norm(aligned[keep], axis=1),
                             np.linalg.norm(sampler.sample(aligned[keep]), axis=1))
    covered, uncovered_dir, how = _coverage(refc, aligned, faces, keep, rms, device)

    tf = np.eye(4)
    tf[:3, :3] = r
    tf[:3, 3] = t + c_ref  # back to the reference's own coordinates
    return ScanComparison(transform=tf, pcc=metrics["pcc"], mare=metrics["mare"], mpre=metrics["mpre"],
                          covered_fraction=covered, rms=rms, iterations=iters, converged=info["converged"],
                          last_move=info["last_move"], coverage_radius=how["radius"],
                          uncovered_direction=uncovered_dir, n_points=len(pts), n_inliers=int(keep.sum()),
                          reference_centroid=c_ref, scan_units=scan_units, reference_units=reference_units)
