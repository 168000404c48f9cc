"""Radial sampling of targets, the star-shape check and the shape metrics (section IV-A).

Radial sampling: for a query point q (a design vertex or face centroid) the ray from the origin
through q is cast on the target (centred on its volume centroid) and its hit becomes the sampled
target point; its radius R is compared with the design radius r = |q|. Rays run on a Warp BVH
(``wp.Mesh``), batched over many query points and many worlds, each world with its own target.

Metrics on paired radii (r design, R sampled target), as in the specification:

- PCC, eq. (10): sum((r - r_mean)(R - R_mean)) / sqrt(sum((r - r_mean)^2) sum((R - R_mean)^2)),
  0.0 for radii without spread (std <= ``FLAT_SPREAD`` x mean);
- MARE = mean |r - R| (metres);
- MPRE = 100 * mean(|r - R| / R) (percent).
"""

from __future__ import annotations

import weakref
from typing import Sequence

import numpy as np
import warp as wp

from .errors import ShapeError, check_whole, numeric_array
from .kernels import raycast
from .mesh import TriMesh

__all__ = [
    "RadialSampler", "radial_sample", "check_star_shaped", "fibonacci_directions",
    "pcc", "mare", "mpre", "shape_metrics", "radial_metrics", "vertex_area_shares", "paired_radii",
]

# Tilt (rad) of the retry rays cast when a ray slips between faces at a vertex or edge.
RAY_JITTER = 1.0e-4
# Ray directions of the star check beside the target's own vertex and face directions.
STAR_DIRECTIONS = 20000
# Relative spread (std / mean) of radii below which they have no shape: PCC 0 (float32 rounding is ~1e-7).
FLAT_SPREAD = 1.0e-6
# Crossings counted per ray by the star check (enough to tell 1 from more).
_MAX_CROSSINGS = 8

_samplers: "weakref.WeakKeyDictionary[TriMesh, dict]" = weakref.WeakKeyDictionary()


#: the most directions ``fibonacci_directions`` makes (10^7: 240 MB, about a second)
MAX_DIRECTIONS = 10**7


def fibonacci_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (golden-angle spiral), deterministic;
    1 <= n <= ``MAX_DIRECTIONS``."""
    n = check_whole(n, "the number of directions", ShapeError)
    if n < 1:
        raise ShapeError(f"need at least one direction, got {n}")
    if n > MAX_DIRECTIONS:
        raise ShapeError(f"{n} directions asked for, more than the {MAX_DIRECTIONS:.0e} that are made "
                         f"({n * 24 / 2**30:.0f} GiB); ask for fewer (a few thousand sample a shape to 0.1 %)")
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def _fmt_dirs(dirs: np.ndarray, k: int = 3) -> str:
    return ", ".join("(" + ", ".join(f"{c:+.2f}" for c in d) + ")" for d in dirs[:k])


def _wp_mesh(mesh: TriMesh, device) -> wp.Mesh:
    points = wp.array(mesh.vertices.astype(np.float32), dtype=wp.vec3, device=device)
    indices = wp.array(mesh.faces.reshape(-1).astype(np.int32), dtype=wp.int32, device=device)
    return wp.Mesh(points=points, indices=indices)


def _reach(mesh: TriMesh) -> float:
    """Longest distance from the origin to the mesh, the scale of every ray."""
    return float(np.max(np.linalg.norm(mesh.vertices, axis=1)))


# ---------------------------------------------------------------------------------------- star check
def check_star_shaped(mesh: TriMesh, *, origin=(0.0, 0.0, 0.0), directions: int = STAR_DIRECTIONS,
                      device=None, name: str = "target", _wp_mesh_obj: wp.Mesh | None = None) -> dict:
    """Check that every ray from ``origin`` crosses the closed ``mesh`` exactly once.

    Rays: ``directions`` golden-spiral directions plus the directions of every vertex and face
    centroid (so features at mesh resolution are seen). Along each ray all crossings are counted
    by restarting the BVH query just past the previous hit. A ray may fail in three ways: it
    crosses the surface more than once (not star-shaped), it crosses nothing (the origin is not
    enclosed), or its first crossing enters the solid (the origin lies outside). Raises
    ``ShapeError`` naming the fractions and a few example directions of each failure; returns
    ``{"directions": M}`` when the mesh passes.
    """
    if not isinstance(mesh, TriMesh):
        raise ShapeError(f"{name} must be a TriMesh, got {type(mesh).__name__}")
    device = wp.get_device(device)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    rel_v = mesh.vertices - origin
    rel_c = mesh.face_centroids() - origin
    reach = float(np.max(np.linalg.norm(rel_v, axis=1)))
    lens = np.linalg.norm(rel_v, axis=1)
    if np.min(lens) <= 1e-9 * reach:
        raise ShapeError(f"{name} is not star-shaped from {_fmt_dirs(origin[None])}: the origin lies "
                         f"on its surface (vertex {int(np.argmin(lens))})")
    dirs = np.concatenate([fibonacci_directions(directions), rel_v / lens[:, None],
                           rel_c / np.linalg.norm(rel_c, axis=1, keepdims=True)])
    wmesh = _wp_mesh_obj if _wp_mesh_obj is not None else _wp_mesh(mesh, device)
    o = wp.vec3(*origin.astype(np.float32))
    d_wp = wp.array(dirs.astype(np.float32), dtype=wp.vec3, device=device)
    counts = wp.zeros(len(dirs), dtype=wp.int32, device=device)
    entering = wp.zeros(len(dirs), dtype=wp.int32, device=device)
    wp.launch(raycast.count_crossings_kernel, dim=len(dirs),
              inputs=[wmesh.id, o, 4.0 * reach, RAY_JITTER, 1e-6 * reach, _MAX_CROSSINGS, d_wp],
              outputs=[counts, entering], device=device)
    counts = counts.numpy()
    entering = entering.numpy().astype(bool)
    m = len(dirs)
    multi = counts > 1
    none = counts == 0
    outside = entering & ~multi
    if not (multi.any() or none.any() or outside.any()):
        return {"directions": m}
    failures = [(f, text) for f, text in ((multi, "see the surface more than once"),
                                          (none, "see no surface (the origin is not enclosed)"),
                                          (outside, "enter the solid first (the origin lies outside it)")) if f.any()]
    parts = [f"{f.mean():.1%} {text}" for f, text in failures]  # the first with an example direction
    parts[0] = parts[0].replace("%", "% of the rays", 1) + f", e.g. along {_fmt_dirs(dirs[failures[0][0]], 1)}"
    where = "the origin" if np.allclose(origin, 0.0) else f"the point {_fmt_dirs(origin[None])}"
    if np.linalg.norm(mesh.centroid() - origin) <= 1e-9 * reach:
        where += ", its volume centroid"
    raise ShapeError(
        f"{name} is not star-shaped from {where}: " + "; ".join(parts)
        + ". Radial sampling needs one hit per ray: use a star-shaped target, centred where it sees all of it.")


# ---------------------------------------------------------------------------------------- sampler
class RadialSampler:
    """Radial sampling of one or more targets, batched over worlds.

    ``targets``: a ``TriMesh`` or a sequence of them, each centred where its rays start (the origin).
    The BVHs live on ``device``; ``check=True`` runs ``check_star_shaped`` on each target first.

    Entry points:
    - ``sample(points, target=0)``: numpy (N, 3) -> numpy (N, 3) float64 hits;
    - ``sample_worlds(points, world_targets)``: numpy (W, N, 3) -> (W, N, 3);
    - ``launch(points, mesh_ids, ...)``: device arrays in and out, no host copies, for W simulated
      worlds per control step (``mesh_ids`` from ``self.mesh_ids(world_targets)``).
    """

    def __init__(self, targets, *, device=None, check: bool = True, names: Sequence[str] | None = None):
        if isinstance(targets, TriMesh):
            targets = [targets]
        targets = list(targets)  # not kept: the sampler cache must not hold its keys alive
        if not targets:
            raise ShapeError("RadialSampler needs at least one target")
        for i, t in enumerate(targets):
            if not isinstance(t, TriMesh):
                raise ShapeError(f"target {i} must be a TriMesh, got {type(t).__name__}")
        self.n_targets = len(targets)
        self.names = list(names) if names is not None else [f"target {i}" for i in range(self.n_targets)]
        self.device = wp.get_device(device)
        self._meshes = [_wp_mesh(t, self.device) for t in targets]
        if check:
            for t, m, nm in zip(targets, self._meshes, self.names):
                check_star_shaped(t, device=self.device, name=nm, _wp_mesh_obj=m)
        self._reaches = [_reach(t) for t in targets]
        # float64 face planes, to refine float32 hits on the host
        self._planes = []
        for t in targets:
            n = np.cross(t.vertices[t.faces[:, 1]] - t.vertices[t.faces[:, 0]],
                         t.vertices[t.faces[:, 2]] - t.vertices[t.faces[:, 0]])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            self._planes.append((n, np.einsum("ij,ij->i", n, t.vertices[t.faces[:, 0]])))
        self._index_targets()

    def _index_targets(self) -> None:
        """The per-target tables every query reads, from ``_meshes``, ``_reaches`` and ``_planes``."""
        self.max_t = 4.0 * max(self._reaches)
        self._ids_host = np.array([m.id for m in self._meshes], dtype=np.uint64)
        self._failures = wp.zeros(1, dtype=wp.int32, device=self.device)
        self._plane_offsets = np.cumsum([0] + [len(n) for n, _ in self._planes[:-1]])  # first row of each target
        self._all_normals = np.concatenate([n for n, _ in self._planes])
        self._all_offsets = np.concatenate([o for _, o in self._planes])

    def subset(self, indices, names: Sequence[str] | None = None) -> "RadialSampler":
        """A sampler of targets ``indices`` (in that order, repeats allowed) of this one, sharing its BVHs
        and planes: nothing is built or checked again, and it samples each target exactly as a
        ``RadialSampler`` of those targets alone would (the same BVHs, planes and ray length)."""
        idx = [int(i) for i in indices]
        if not idx or min(idx) < 0 or max(idx) >= self.n_targets:
            raise ShapeError(f"a subset indexes the sampler's {self.n_targets} target(s), got {idx}")
        out = object.__new__(RadialSampler)
        out.n_targets, out.device = len(idx), self.device
        out.names = list(names) if names is not None else [self.names[i] for i in idx]
        out._meshes = [self._meshes[i] for i in idx]
        out._reaches = [self._reaches[i] for i in idx]
        out._planes = [self._planes[i] for i in idx]
        out._index_targets()
        return out

    def mesh_ids(self, world_targets=None) -> wp.array:
        """(W,) uint64 BVH ids on the device: world w samples target ``world_targets[w]``."""
        wt = np.arange(self.n_targets) if world_targets is None else np.asarray(world_targets, dtype=np.int64)
        if wt.ndim != 1 or wt.size == 0 or wt.min() < 0 or wt.max() >= self.n_targets:
            raise ShapeError(f"world_targets must index the {self.n_targets} target(s), got {wt.tolist()}")
        return wp.array(self._ids_host[wt], dtype=wp.uint64, device=self.device)

    def launch(self, points: wp.array, mesh_ids: wp.array, *, hits_out: wp.array | None = None,
               radii_out: wp.array | None = None, faces_out: wp.array | None = None, check: bool = True):
        """Sample on the device. ``points``: wp.array2d of vec3, shape (W, N); ``mesh_ids``: (W,).

        Returns ``(hits, radii, faces)`` device arrays of shape (W, N) (vec3, float32, int32),
        reusing the ``*_out`` arrays when given. ``check=True`` reads back one failure counter and
        raises ``ShapeError`` if any ray failed; with ``check=False`` nothing is read back and the
        caller must call ``raise_failures(points, faces)`` later: failed rays hold NaN hits and a
        negative face (``RAY_MISS`` -1: nothing hit; ``RAY_NO_DIRECTION`` -2: query at the origin).
        """
        if points.ndim != 2 or points.dtype != wp.vec3:
            raise ShapeError(f"points must be a 2-D array of wp.vec3 (W, N), got {points.ndim}-D {points.dtype}")
        w, n = points.shape
        if mesh_ids.shape[0] != w:
            raise ShapeError(f"mesh_ids has {mesh_ids.shape[0]} entries for {w} worlds of points")
        dev = self.device
        hits = hits_out if hits_out is not None else wp.empty((w, n), dtype=wp.vec3, device=dev)
        radii = radii_out if radii_out is not None else wp.empty((w, n), dtype=wp.float32, device=dev)
        faces = faces_out if faces_out is not None else wp.empty((w, n), dtype=wp.int32, device=dev)
        self._failures.zero_()
        wp.launch(raycast.radial_sample_kernel, dim=(w, n), inputs=[mesh_ids, self.max_t, RAY_JITTER, points],
                  outputs=[hits, radii, faces, self._failures], device=dev)
        if check and int(self._failures.numpy()[0]) > 0:
            self.raise_failures(points, faces, mesh_ids)
        return hits, radii, faces

    def raise_failures(self, points, faces, mesh_ids=None) -> None:
        """Raise ``ShapeError`` describing failed rays (negative faces); return if there are none."""
        f = faces.numpy() if isinstance(faces, wp.array) else np.asarray(faces)
        bad = f < 0
        if not bad.any():
            return
        p = points.numpy() if isinstance(points, wp.array) else np.asarray(points)
        p = p.reshape(f.shape + (3,))
        ids = mesh_ids.numpy() if isinstance(mesh_ids, wp.array) else None
        wi, ii = np.argwhere(bad)[0]
        tname = self.names[int(np.flatnonzero(self._ids_host == ids[wi])[0])] if ids is not None else "the target"
        n_zero = int(np.sum(f == -2))
        n_miss = int(np.sum(f == -1))
        msg = (f"radial sampling failed for {int(bad.sum())} of {f.size} query points "
               f"(first: world {wi}, point {ii} at {_fmt_dirs(p[wi, ii][None])} m, sampling {tname}): ")
        why = []
        if n_miss:
            why.append(f"{n_miss} ray(s) from the origin hit no surface, so the target does not enclose "
                       f"the origin along them (centre it on its volume centroid and check it is star-shaped)")
        if n_zero:
            why.append(f"{n_zero} query point(s) lie at the origin, where the ray direction is undefined")
        raise ShapeError(msg + "; ".join(why))

    def sample_worlds(self, points, world_targets=None) -> np.ndarray:
        """Hits (W, N, 3) float64 for query points (W, N, 3); world w samples ``world_targets[w]``."""
        return self.sample_worlds_with_faces(points, world_targets)[0]

    def sample_worlds_with_faces(self, points, world_targets=None):
        """``(hits, faces, on_plane)`` for query points (W, N, 3): the float64 hits (W, N, 3) of
        ``sample_worlds``, the target face each ray hit (W, N) int64, and (W, N) bool, True where the
        hit lies on that face's plane (float64 refinement; False: the float32 hit is kept, for a ray
        nearly parallel to the face or a plane answer far from the float32 one)."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 3 or p.shape[2] != 3:
            raise ShapeError(f"points must have shape (W, N, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ShapeError("query points must be finite; got NaN or inf")
        wt = np.arange(self.n_targets) if world_targets is None else np.asarray(world_targets, dtype=np.int64)
        if wt.shape != (p.shape[0],):
            raise ShapeError(f"world_targets must give one target per world ({p.shape[0]}), got {wt.tolist()}")
        ids = self.mesh_ids(wt)
        pw = wp.array(p.astype(np.float32), dtype=wp.vec3, device=self.device)
        _, radii, faces = self.launch(pw, ids)
        radii = radii.numpy().astype(np.float64)
        faces = faces.numpy().astype(np.int64)
        on_plane = np.zeros(faces.shape, dtype=bool)
        # Refine in float64: intersect the exact ray with the plane of the face hit (float32 only
        # chose the face). Keeps hits on the original ray and exact at the target's own vertices.
        # All worlds at once: every target's planes stacked, world w's faces offset to its target's.
        d = p / np.linalg.norm(p, axis=2, keepdims=True)
        rows = self._plane_offsets[wt][:, None] + faces
        nf, of = self._all_normals[rows], self._all_offsets[rows]
        dn = np.einsum("wij,wij->wi", d, nf)
        ok = np.abs(dn) > 1e-3
        t64 = np.where(ok, of / np.where(ok, dn, 1.0), radii)
        # keep float32 where the plane answer is far off (a retry hit on a neighbouring face)
        on_plane = ok & (np.abs(t64 - radii) < 1e-3 * self.max_t)
        radii = np.where(on_plane, t64, radii)
        return d * radii[..., None], faces, on_plane

    def face_planes(self, target: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(normals, offsets)`` of target ``target``'s faces in float64: (F, 3) unit outward normals
        n_f and (F,) offsets n_f . (a vertex of f), so that face f lies on the plane n_f . y = offset_f."""
        if not 0 <= int(target) < self.n_targets:
            raise ShapeError(f"target {target} is not one of the sampler's {self.n_targets} target(s)")
        return self._planes[int(target)]

    def sample(self, points, target: int = 0) -> np.ndarray:
        """Hits (N, 3) float64 on target ``target`` of the rays from the origin through ``points``."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ShapeError(f"points must have shape (N, 3), got {p.shape}")
        return self.sample_worlds(p[None], [target])[0]


def _sampler_for(target: TriMesh, device=None) -> RadialSampler:
    """A cached single-target sampler (targets are immutable, so their BVH and check are reused)."""
    dev = str(wp.get_device(device))
    per = _samplers.setdefault(target, {})
    if dev not in per:
        per[dev] = RadialSampler(target, device=dev)
    return per[dev]


def radial_sample(target: TriMesh, points, *, device=None) -> np.ndarray:
    """(N, 3) float64: hit on ``target`` of the ray from the origin through each query point."""
    return _sampler_for(target, device).sample(points)


# ---------------------------------------------------------------------------------------- metrics
def vertex_area_shares(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(W, V) the area each vertex stands for (a third of each adjacent face) of the (W, V, 3) ``points``
    triangulated by ``faces``: the weights of the fit objective (``objectives.radial.fit_objective``)."""
    W, V = points.shape[:2]
    p = points[:, faces]  # (W, F, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0]), axis=2)  # (W, F)
    idx = (np.arange(W)[:, None, None] * V + faces[None]).reshape(-1)
    return np.bincount(idx, weights=np.repeat(area / 3.0, 3, axis=1).reshape(-1), minlength=W * V).reshape(W, V)


def paired_radii(r, R, what: str):
    """r, R as flat float64 arrays of one length, finite and not empty; else ``ShapeError`` naming ``what``."""
    r = numeric_array(r, f"{what}: r (radii, m)", ShapeError).reshape(-1)
    R = numeric_array(R, f"{what}: R (radii, m)", ShapeError).reshape(-1)
    if r.shape != R.shape:
        raise ShapeError(f"{what}: r and R must have the same length, got {r.size} and {R.size}")
    if r.size == 0:
        raise ShapeError(f"{what}: no radii given")
    for arr, nm in ((r, "r"), (R, "R")):
        bad = ~np.isfinite(arr)
        if bad.any():
            raise ShapeError(f"{what}: {nm}[{int(np.flatnonzero(bad)[0])}] is not finite "
                             f"({int(bad.sum())} non-finite value(s))")
    return r, R


def pcc(r, R) -> float:
    """Pearson correlation of design radii r and sampled target radii R, eq. (10).

    Radii without spread have no shape to correlate: where the standard deviation of r or of R is at
    most ``FLAT_SPREAD`` (1e-6) times its mean (a sphere about the origin, whose float32 radii differ
    only by rounding, ~1e-7 relative), the PCC is 0.0 exactly.
    """
    r, R = paired_radii(r, R, "PCC")
    if r.size < 2:
        raise ShapeError("PCC needs at least two radii")
    if _flat(r) or _flat(R):
        return 0.0
    dr, dR = r - r.mean(), R - R.mean()
    return float(np.dot(dr, dR) / np.sqrt(float(np.dot(dr, dr)) * float(np.dot(dR, dR))))


def _flat(x: np.ndarray) -> bool:
    """True where radii ``x`` have no spread beyond rounding: std(x) <= FLAT_SPREAD * mean(|x|)."""
    return float(np.std(x)) <= FLAT_SPREAD * float(np.mean(np.abs(x)))


def mare(r, R) -> float:
    """Mean absolute radial error mean|r - R| (m)."""
    r, R = paired_radii(r, R, "MARE")
    return float(np.mean(np.abs(r - R)))


def mpre(r, R) -> float:
    """Mean percent radial error 100 * mean(|r - R| / R) (%)."""
    r, R = paired_radii(r, R, "MPRE")
    if np.any(R <= 0):
        raise ShapeError(f"MPRE: sampled radius R[{int(np.flatnonzero(R <= 0)[0])}] is not positive")
    return float(100.0 * np.mean(np.abs(r - R) / R))


def radial_metrics(r, R) -> dict:
    """``{"pcc", "mare", "mpre"}`` of paired radii."""
    if isinstance(r, TriMesh) or isinstance(R, TriMesh):
        raise ShapeError("radial_metrics takes paired radii (arrays, m), not meshes; for a mesh against a target "
                         "use shape_metrics(mesh, target)")
    return {"pcc": pcc(r, R), "mare": mare(r, R), "mpre": mpre(r, R)}


def shape_metrics(mesh, target: TriMesh, *, at: str = "vertices", sampler: RadialSampler | None = None,
                  target_index: int = 0, device=None) -> dict:
    """PCC, MARE and MPRE of ``mesh`` against ``target`` by radial sampling.

    ``mesh``: a TriMesh (or (V, 3) vertices with ``at="vertices"``), in the target's frame.
    ``at="vertices"`` samples through the vertices, ``at="faces"`` through the face centroids.
    """
    if at not in ("vertices", "faces"):
        raise ShapeError(f"at must be 'vertices' or 'faces', got {at!r}")
    if isinstance(mesh, TriMesh):
        q = mesh.vertices if at == "vertices" else mesh.face_centroids()
    elif at == "vertices":
        q = np.asarray(mesh, dtype=np.float64)
    else:
        raise ShapeError("at='faces' needs a TriMesh")
    hits = (sampler.sample(q, target_index) if sampler is not None
            else radial_sample(target, q, device=device))
    return radial_metrics(np.linalg.norm(q, axis=1), np.linalg.norm(hits, axis=1))
