"""Ray throughput of radial sampling: Warp BVH vs trimesh's pure-numpy ray query.

``bench_rays`` casts radial rays (from the origin, as radial sampling does) at a target of about
``triangles`` faces, with the Warp kernel of ``RadialSampler.launch`` (device arrays in and out,
after a compile/warm-up launch) and with trimesh's ``ray_triangle_id`` (the numpy narrow phase of
``RayMeshIntersector``) in the same run; each figure is the minimum over ``repeats``.
trimesh's broad phase needs rtree, which is not a dependency here, so it is given a numpy
box-overlap index with the same interface (``bounds``, ``intersection``). A second trimesh row
("trimesh narrow") replays precomputed candidates instead, timing trimesh as if its broad phase
were free: its best case. trimesh is timed on at most ``trimesh_max_rays`` rays per count, which
the row states.

Run ``python -m warp_shape.benchmarks.rays [--device cuda:0] [--json out.json]`` or ``warp-shape bench rays``.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import warp as wp

from warp_shape.sampling import RadialSampler
from warp_shape.targets import target

from .common import min_time

__all__ = ["bench_rays", "format_table"]


class _BoxIndex:
    """rtree stand-in for trimesh: triangle boxes overlapping a query box, by numpy comparison."""

    def __init__(self, triangles: np.ndarray):
        self.lo = triangles.min(axis=1)
        self.hi = triangles.max(axis=1)
        self.bounds = np.concatenate([self.lo.min(axis=0), self.hi.max(axis=0)])

    def intersection(self, box):
        box = np.asarray(box)
        hit = np.all(self.lo <= box[3:], axis=1) & np.all(self.hi >= box[:3], axis=1)
        return np.flatnonzero(hit)


class _ReplayIndex:
    """Hands trimesh precomputed candidates, one list per ray in call order: times trimesh's
    narrow phase as if its broad phase were free (an upper bound on trimesh with rtree)."""

    def __init__(self, bounds, candidates):
        self.bounds = bounds
        self._candidates = candidates
        self._next = 0

    def intersection(self, box):
        out = self._candidates[self._next]
        self._next += 1
        return out


def _target_with(triangles: int):
    # radial targets have 20 * 4**r faces: take the resolution nearest to the request
    res = int(np.clip(np.round(np.log(max(triangles, 20) / 20.0) / np.log(4.0)), 1, 6))
    return target("heart", resolution=res)


def bench_rays(device="cpu", counts=(10**4, 10**6), triangles: int = 20000, repeats: int = 3,
               trimesh_max_rays: int = 10**4, seed: int = 0, progress=None) -> list[dict]:
    """Rays per second of Warp radial sampling and of trimesh, one row per (engine, ray count);
    ``progress(text)`` is told as each row is measured."""
    say = progress or (lambda text: None)
    device = wp.get_device(device)
    mesh = _target_with(triangles)
    sampler = RadialSampler(mesh, device=device, check=False)
    ids = sampler.mesh_ids()
    rng = np.random.default_rng(seed)
    rows = []

    # warm-up: compiles/loads the kernel module, outside the timings
    warm = wp.array(rng.normal(size=(1, 64, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    sampler.launch(warm, ids)

    tri = mesh.vertices[mesh.faces]
    index = _BoxIndex(tri)
    from trimesh.ray.ray_triangle import ray_bounds, ray_triangle_id

    for n in counts:
        n = int(n)
        dirs = rng.normal(size=(n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        pts = wp.array(dirs[None].astype(np.float32), dtype=wp.vec3, device=device)
        hits = wp.empty((1, n), dtype=wp.vec3, device=device)
        radii = wp.empty((1, n), dtype=wp.float32, device=device)
        faces = wp.empty((1, n), dtype=wp.int32, device=device)

        def warp_run():
            sampler.launch(pts, ids, hits_out=hits, radii_out=radii, faces_out=faces, check=False)
            wp.synchronize_device(device)

        secs = min_time(warp_run, repeats)
        sampler.raise_failures(pts, faces, ids)  # every ray must have hit
        rows.append(dict(engine="warp", device=str(device), triangles=mesh.n_faces, rays=n,
                         rays_timed=n, seconds=secs, rays_per_s=n / secs, note=""))
        say(f"  rays: warp, {n} rays: {n / secs:.3g} rays/s; trimesh next")

        m = min(n, int(trimesh_max_rays))
        origins = np.zeros((m, 3))
        subset = f"timed on {m} of the {n} rays; " if m < n else ""

        def trimesh_run(tree):
            _, idx_ray, _ = ray_triangle_id(tri, origins, dirs[:m], tree=tree, multiple_hits=False)
            if len(np.unique(idx_ray)) != m:
                raise RuntimeError("trimesh missed rays in the benchmark")

        secs_t = min_time(lambda: trimesh_run(index), repeats)
        rows.append(dict(engine="trimesh", device="cpu (numpy)", triangles=mesh.n_faces, rays=n,
                         rays_timed=m, seconds=secs_t * n / m, rays_per_s=m / secs_t,
                         note=subset + "broad phase: numpy box index standing in for rtree"))

        # the same query with the broad phase precomputed (untimed): trimesh's best case
        bounds = ray_bounds(origins, dirs[:m], index.bounds)
        cands = [index.intersection(b) for b in bounds]
        secs_n = min_time(lambda: trimesh_run(_ReplayIndex(index.bounds, cands)), repeats)
        rows.append(dict(engine="trimesh narrow", device="cpu (numpy)", triangles=mesh.n_faces, rays=n,
                         rays_timed=m, seconds=secs_n * n / m, rays_per_s=m / secs_n,
                         note=subset + "broad phase excluded (trimesh's best case with a free rtree)"))
        say(f"  rays: trimesh, {n} rays: {m / secs_t:.3g} rays/s (narrow phase {m / secs_n:.3g})")
    return rows


def format_table(rows: list[dict]) -> str:
    """Fixed-width table of ``bench_rays`` rows, with Warp's speed-up over trimesh per ray count."""
    trimesh_rate = {r["rays"]: r["rays_per_s"] for r in rows if r["engine"] == "trimesh"}
    # speed-up over trimesh's best case too
    best_rate = {r["rays"]: r["rays_per_s"] for r in rows if r["engine"] == "trimesh narrow"}
    head = ["engine", "device", "triangles", "rays", "rays/s", "vs trimesh", "vs narrow", "note"]
    body = []
    for r in rows:
        a, b = trimesh_rate.get(r["rays"]), best_rate.get(r["rays"])
        body.append([r["engine"], r["device"], str(r["triangles"]), f"{r['rays']:.0e}",
                     f"{r['rays_per_s']:.3g}", f"{r['rays_per_s'] / a:.1f}x" if a else "",
                     f"{r['rays_per_s'] / b:.1f}x" if b else "", r.get("note", "")])
    widths = [max(len(x) for x in col) for col in zip(head, *body)]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()
    return "\n".join([line(head), line(["-" * w for w in widths])] + [line(b) for b in body])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--triangles", type=int, default=20000)
    ap.add_argument("--json", help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    rows = bench_rays(device=args.device, triangles=args.triangles)
    print(format_table(rows))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
