"""``warp-shape sweep subsets|grid``: many designs, on Ray or one after another, into one results table."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..limits import MAX_ACTUATORS
from ..sweeps import SweepError, sweep
from .options import add_bounded, check_device

__all__ = ["register", "run"]


def _common(sp) -> None:
    sp.add_argument("scene", nargs="?", default=None, help="design problem: a shipped scene name or .usda file "
                    "(default oval_heart, as `warp-shape design`)")
    sp.add_argument("--targets", nargs="+", help="target names (oval pear heart cube) or mesh files")
    add_bounded(sp, "--actuators", 1, MAX_ACTUATORS, type=int, default=None,
                help="number of IPAMs of every run (default: the scene's)")
    sp.add_argument("--set", dest="fixed", action="append", default=[], metavar="NAME=VALUE",
                    help="a setting for every run (repeatable), e.g. --set method=paper --set subdivisions=2")
    sp.add_argument("--out", default="sweep", help="sweep folder: results.csv, results.json, summary, runs/")
    sp.add_argument("--backend", choices=("ray", "serial"), default="ray",
                    help="ray (default: one Ray task per run) or serial (one after another in this process)")
    sp.add_argument("--address", default=None, help="join the Ray cluster at HOST:PORT (or auto) instead of "
                    "starting a local instance")
    add_bounded(sp, "--workers", 1, 1024, type=int, default=None, help="runs at a time (default: the CPUs Ray sees)")
    add_bounded(sp, "--retries", 0, 100, type=int, default=1, help="Ray retries of a run whose worker process died")
    sp.add_argument("--restart", action="store_true", help="discard the folder's earlier results and run all")
    sp.add_argument("--device", default="cpu", help="Warp device of each run: cpu or cuda (one GPU per Ray task)")
    sp.add_argument("--json", action="store_true", help="print the rows as JSON")
    sp.add_argument("--verbose", action="store_true", help="show Warp's compile messages")
    sp.set_defaults(func=run)


def register(subparsers) -> None:
    """Add the ``sweep`` subcommand with its ``subsets`` and ``grid`` kinds."""
    s = subparsers.add_parser("sweep", help="many designs: every subset of targets, or a grid of settings "
                              "(on Ray; docs/sweeps.md)")
    kinds = s.add_subparsers(dest="kind", required=True)
    sub = kinds.add_parser("subsets", help="design for every non-empty subset of the targets (Fig. 11)",
                           description="Design a display for every non-empty subset of the targets (the paper's "
                                       "Fig. 11), each run a `warp-shape design` into runs/, rows in results.csv.")
    _common(sub)
    sub.add_argument("--param", action="append", default=[], metavar="NAME=V1,V2",
                     help="also sweep a setting over these values (repeatable)")
    grid = kinds.add_parser("grid", help="design for every combination of setting values (Fig. 12)",
                            description="Design a display for every combination of the --param values (the "
                                        "paper's Fig. 12), each run a `warp-shape design` into runs/, rows in "
                                        "results.csv.")
    _common(grid)
    grid.add_argument("--param", action="append", default=[], required=True, metavar="NAME=V1,V2",
                      help="a swept setting and its values (repeatable): actuators, subdivisions, or any "
                      "designer/controller/simulation/material setting, e.g. actuators=5,10,20")


def _fixed(specs) -> dict:
    out = {}
    for spec in specs:
        name, sep, value = spec.partition("=")
        if not sep or not name.strip():
            raise SweepError(f"--set needs NAME=VALUE (e.g. --set method=paper), got {spec!r}")
        out[name.strip()] = value.strip()
    return out


def run(args) -> int:
    """Run the sweep; print the summary table (or the rows as JSON) and where the results are."""
    if args.address is None:  # runs on this machine: its device must be here (a cluster's workers have their own)
        check_device(args.device)
    fixed = _fixed(args.fixed)
    swept = {spec.partition("=")[0].strip() for spec in args.param}
    both = sorted(swept & set(fixed))
    if both:
        raise SweepError(f"{both[0]} is both swept (--param) and fixed (--set); the --set would be dropped: give "
                         f"it with one of them")
    res = sweep(args.kind, args.scene, targets=args.targets, actuators=args.actuators, params=args.param,
                fixed=fixed, out=args.out, backend=args.backend, workers=args.workers,
                address=args.address, device=args.device, retries=args.retries, restart=args.restart)
    if args.json:
        print(json.dumps(res.rows, indent=1))
    else:
        print((Path(args.out) / "summary.md").read_text())
        ray_note = f", Ray start-up {res.startup_s:.1f} s" if res.startup_s else ""
        print(f"{res.ran} run(s) now, {res.skipped} already finished, {len(res.failed)} failed; "
              f"wall {res.wall_s:.1f} s{ray_note}; results in {args.out}/results.csv")
    if res.failed:
        print(f"warp-shape: {len(res.failed)} run(s) failed (see the error column); rerun the same command "
              f"to retry them", file=sys.stderr)
        return 1
    return 0
