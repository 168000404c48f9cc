"""Scan coverage: the share of the reference surface within a distance of the scan, the same for a
mesh and for a point cloud of any density; ICP that stops at its limit says so, with its residual."""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.scan import IcpConvergenceWarning, compare_scan, surface_samples

R = 0.04  # m
PRESENT = 0.6  # a one-sided scan: the part of the sphere above z0 (Archimedes: area share (R - z0) / 2R)
Z0 = R - 2 * R * PRESENT
SHIFT = np.array([0.013, -0.007, 0.021])  # the scan is not where the reference is


@pytest.fixture(scope="module")
def reference():
    return ws.icosphere(4, R)


def _random_cloud(n, seed):
    p = surface_samples(ws.icosphere(5, R), n, seed=seed)
    p = R * p / np.linalg.norm(p, axis=1, keepdims=True)
    return p[p[:, 2] > Z0]


@pytest.mark.parametrize("kind,n", [("random", 20000), ("random", 1500), ("grid", 3)])
def test_point_cloud_coverage_matches_the_present_share(reference, kind, n):
    """Dense (12000 random points, 1 mm apart) and sparse (930 random points 3.6 mm apart; 380 grid
    points 5.6 mm apart, a sphere's vertices) clouds all measure 60 % within 3 percentage points
    (random clouds of 930 points: 60.8 +- 0.5 % over seeds)."""
    pts = _random_cloud(n, seed=n) if kind == "random" else ws.icosphere(n, R).vertices
    pts = pts[pts[:, 2] > Z0] + SHIFT
    res = compare_scan(pts, reference)
    assert res.covered_fraction == pytest.approx(PRESENT, abs=0.03), (kind, len(pts), res.covered_fraction)
    # the missing part is below the scan (a sphere aligns in any rotation: map the scan's -z over)
    assert res.uncovered_direction @ (res.transform[:3, :3] @ [0.0, 0.0, -1.0]) > 0.95
    assert res.coverage_radius > 0


def test_mesh_scan_coverage_matches_the_present_share(reference):
    fine = ws.icosphere(5, R)
    keep = fine.face_centroids()[:, 2] > Z0
    truth = float(fine.face_areas()[keep].sum() / fine.face_areas().sum())
    res = compare_scan((fine.vertices + SHIFT, fine.faces[keep]), reference)
    assert res.covered_fraction == pytest.approx(truth, abs=0.03)
    assert res.converged


def test_point_to_point_stopping_at_its_limit_warns_with_the_residual(reference, tmp_path, capsys):
    import trimesh

    from warp_shape.cli.compare import register

    pts = _random_cloud(3000, seed=2) + SHIFT
    with pytest.warns(IcpConvergenceWarning, match=r"did not converge in 2 iterations: residual rms [0-9.]+ mm"):
        res = compare_scan(pts, reference, method="point_to_point", max_iterations=2)
    assert not res.converged and res.last_move > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", IcpConvergenceWarning)  # a converged run is quiet
        assert compare_scan(pts, reference).converged

    path = tmp_path / "scan.ply"
    trimesh.PointCloud(pts).export(str(path))
    parser = argparse.ArgumentParser(prog="warp-shape")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["compare", str(path), "--to", str(tmp_path / "ref.stl"), "--method", "point_to_point",
                              "--max-iterations", "2"])
    reference.to_trimesh().export(str(tmp_path / "ref.stl"))
    assert args.func(args) == 0
    out = capsys.readouterr()
    assert "warning: ICP (point_to_point) did not converge" in out.err and "residual rms" in out.err
    assert "not converged" in out.out and "% of the reference surface" in out.out
