"""``warp-shape compare``: a 3-D scan against a design or target shape (section V-D).

``register(subparsers)`` adds the subcommand to the ``warp-shape`` parser; it sets ``func=run``,
which returns the exit status (0 on success, 2 on a reported error).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import numpy as np

from ..errors import ShapeError, WarpShapeError
from ..io.scene_read import load_actuated_shape
from ..scan import IcpConvergenceWarning, compare_scan
from .options import add_bounded, check_device

__all__ = ["register", "run", "format_comparison"]


def register(subparsers) -> argparse.ArgumentParser:
    """Add the ``compare`` subcommand to an ``argparse`` subparsers object."""
    p = subparsers.add_parser(
        "compare",
        help="compare a 3-D scan with a design or target shape (PCC, MARE, MPRE, coverage)",
        description="Align a scan (open, partial meshes and point clouds accepted) to a reference "
                    "shape by principal axes and ICP, then compare them by radial sampling.")
    p.add_argument("scan", help="scan file: any mesh or point cloud trimesh reads (PLY, STL, OBJ, GLB, ...)")
    p.add_argument("--to", required=True, dest="reference", metavar="REFERENCE",
                   help="reference: a closed mesh file, a target name (oval, pear, heart, cube), or a design: "
                        "its design.usda (with --target) or an actuation_<target>.usdc, compared at the "
                        "simulated shape the design's controlled run achieved")
    p.add_argument("--target", default=None, metavar="NAME",
                   help="with a design as --to: the target whose actuated shape to compare with (default: the "
                        "design's only target)")
    p.add_argument("--time", type=float, default=None, metavar="S",
                   help="with a design as --to: the time in the target's valve schedule, s (default: its end, "
                        "the achieved shape)")
    p.add_argument("--units", choices=("auto", "m", "mm"), default="auto",
                   help="length unit of the scan file (and of a reference mesh file): auto (default) reads a "
                        "file as millimetres when its size is a display's in mm, else as metres")
    p.add_argument("--reference-units", choices=("auto", "m", "mm"), default=None,
                   help="length unit of a reference mesh file, when it differs from the scan's (default: --units; "
                        "targets and designs are in metres)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--device", default="cpu", help="Warp device, e.g. cpu or cuda:0 (default cpu)")
    p.add_argument("--method", choices=("point_to_plane", "point_to_point"), default="point_to_plane",
                   help="ICP update (default point_to_plane)")
    add_bounded(p, "--max-iterations", 1, 10000, type=int, default=200, help="ICP iteration limit (default 200)")
    p.set_defaults(func=run)
    return p


def _axis_angle(r: np.ndarray) -> tuple[float, np.ndarray]:
    angle = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    n = np.linalg.norm(axis)
    return angle, (axis / n if n > 1e-12 else np.array([0.0, 0.0, 1.0]))


def _vec(v, fmt="{:+.2f}") -> str:
    return "(" + ", ".join(fmt.format(x) for x in v) + ")"


_UNIT_WORDS = {"m": "read in metres", "mm": "read in millimetres"}


def format_comparison(res, *, scan: str = "", reference: str = "") -> str:
    """A readable table of a ``ScanComparison``."""
    angle, axis = _axis_angle(res.transform[:3, :3])
    rows = [
        ("scan", f"{scan}  ({_UNIT_WORDS[res.scan_units]})" if scan else ""),
        ("reference", f"{reference}  ({_UNIT_WORDS[res.reference_units]})" if reference else ""),
        ("PCC", f"{res.pcc:.4f}"),
        ("MARE", f"{res.mare * 1e3:.3f} mm"),
        ("MPRE", f"{res.mpre:.2f} %"),
        ("covered", f"{100 * res.covered_fraction:.1f} % of the reference surface (within "
                    f"{getattr(res, 'coverage_radius', 0.0) * 1e3:.2f} mm of the scan)"),
        ("uncovered", "nothing" if res.uncovered_direction is None
         else f"mostly toward {_vec(res.uncovered_direction)} from the reference centroid"),
        ("ICP", f"{res.iterations} iteration{'s' if res.iterations != 1 else ''}"
                f"{'' if getattr(res, 'converged', True) else ' (iteration limit: not converged)'}, "
                f"rms {res.rms * 1e3:.3f} mm, {res.n_inliers} of {res.n_points} scan points inliers"),
        ("rotation", f"{angle:.2f} deg about {_vec(axis)}"),
        ("translation", _vec(res.transform[:3, 3] * 1e3, "{:+.2f}") + " mm"),
    ]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows if v != "")


_DESIGN_EXTENSIONS = (".usda", ".usdc", ".usd")


def _reference(args):
    """(reference for ``compare_scan``, its units, how to name it): a design's actuated shape where
    ``--to`` is a scene, else the mesh file or target name as given."""
    is_design = str(args.reference).lower().endswith(_DESIGN_EXTENSIONS)
    if not is_design:
        if args.target is not None or args.time is not None:
            raise ShapeError(f"--target and --time pick a design's actuated shape; --to {args.reference} is not a "
                             f"design (give its design.usda or an actuation_<target>.usdc)")
        return args.reference, args.reference_units or args.units, str(args.reference)
    mesh, info = load_actuated_shape(args.reference, target=args.target, time_s=args.time)
    what = f"{info['file']} (target {info['target']}, simulated shape at {info['time_s']:.3f} of {info['duration_s']:.3f} s)"
    return mesh, "m", what


def run(args) -> int:
    """Compare the scan with the reference; print the table (or JSON)."""
    try:
        check_device(args.device)
        reference, reference_units, named = _reference(args)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IcpConvergenceWarning)
            res = compare_scan(args.scan, reference, device=args.device, method=args.method,
                               max_iterations=args.max_iterations, scan_units=args.units,
                               reference_units=reference_units)
    except WarpShapeError as exc:
        print(f"warp-shape compare: error: {exc}", file=sys.stderr)
        return 2
    for w in caught:
        if issubclass(w.category, IcpConvergenceWarning):
            print(f"warp-shape compare: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if args.json:
        out = res.to_dict()
        out.update(scan=str(args.scan), reference=named)
        print(json.dumps(out, indent=2))
    else:
        print(format_comparison(res, scan=str(args.scan), reference=named))
    return 0
