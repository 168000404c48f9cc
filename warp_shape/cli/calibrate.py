"""``warp-shape calibrate``: fit a design's material and IPAM parameters to scans of the built device."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ..calibration import CALIBRATION_PARAMETERS, DEFAULT_WRT, HYPERELASTIC_WRT, calibrate
from ..calibration.files import (bounds_reached, calibration_data, calibration_markdown, read_manifest, write_calibration,
                                 write_residual_figures)
from ..calibration.parameters import check_law, check_wrt, default_wrt
from ..io.atomic import StagedFolder, atomic_write
from .options import (add_common_args, add_membrane_arg, check_device, check_out, check_rerun, commit, open_recorder,
                      resolve_design_and_targets, with_membrane)

__all__ = ["register", "run", "CALIBRATION_OUTPUTS"]

#: the files a calibration writes into --out
CALIBRATION_OUTPUTS = ("calibration.json", "calibration.md")


def register(subparsers) -> None:
    """Add the ``calibrate`` subcommand."""
    c = subparsers.add_parser(
        "calibrate", help="fit the model (E t, bending, IPAM k and A, rest scale) to scans of the built device",
        description="Replay each scan's control state on the design, align the scan (unknown pose, as compare), "
                    "and fit the chosen parameters by damped Gauss-Newton with a robust loss. Writes "
                    "calibration.json (the file design, control and export take with --calibration), "
                    "calibration.md and a residual map per scan.")
    c.add_argument("manifest", help="manifest (JSON) listing the scans and the control state of each; its paths are "
                                    "relative to its folder (docs/calibration.md)")
    c.add_argument("--design", required=True, help="the design that was built: its design.usda (e.g. out/design.usda) "
                                                   "or a shipped scene name (e.g. cube_fig6)")
    c.add_argument("--wrt", nargs="+", default=None, choices=list(CALIBRATION_PARAMETERS),
                   help=f"parameters to fit (default: the manifest's \"wrt\", else {' '.join(DEFAULT_WRT)} on springs, "
                        f"{' '.join(HYPERELASTIC_WRT)} on a hyperelastic membrane)")
    c.add_argument("--regions", nargs="+", default=None, metavar="REGION",
                   help="parts of the membrane whose E t is fitted on its own (region_stretch): plug, "
                        "cell_boundaries, patches:N (default: the manifest's \"regions\", else none)")
    add_membrane_arg(c, "the design that was built")
    add_common_args(c, out="out/calibration")
    c.set_defaults(func=run)


def _print(result, out: Path, written) -> None:
    print(calibration_markdown(result))
    for n in result.notes:
        print(f"warning: not identifiable: {n}")
    for n in result.poorly_determined:
        print(f"warning: poorly determined: {n}")
    for n in bounds_reached(result):
        print(f"warning: at a bound: {n}")
    print(f"wrote {', '.join(Path(p).name for p in written)} to {out}/; use it with "
          f"warp-shape control DESIGN --calibration {out / 'calibration.json'}")


def calibration_output(name: str) -> bool:
    """Whether a file name is one a calibration writes (``CALIBRATION_OUTPUTS``, ``residuals_<k>.png|svg``)."""
    return name in CALIBRATION_OUTPUTS or name.startswith("residuals_")


def _progress(line: str) -> None:
    """A progress line on stderr, flushed: it reaches a log file as it happens, not only a terminal."""
    print(f"calibrate: {line}", file=sys.stderr, flush=True)


def run(args) -> int:
    """Read and check every input (``--out`` first), fit, then write the calibration file, the report
    and the figures, staged and swapped into ``--out`` whole."""
    staged = StagedFolder(args.out, owned=calibration_output, command="calibrate")
    check_out(staged)
    check_device(args.device)
    check_rerun(args, staged, inputs=[args.manifest, args.design])
    out = Path(args.out)
    design, _, _ = resolve_design_and_targets(args.design, None)
    design = with_membrane(design, args.membrane)
    observations, manifest_wrt, manifest_regions = read_manifest(args.manifest, design)
    wrt = check_wrt(args.wrt) if args.wrt else (manifest_wrt or default_wrt(design))
    check_law(design, wrt)
    with staged.writing():
        result = calibrate(design, observations, wrt=wrt, regions=args.regions or manifest_regions,
                           device=args.device, progress=_progress)  # regions checked before any replay
        written = [write_calibration(result, design, staged.path / "calibration.json"),
                   atomic_write(staged.path / "calibration.md", calibration_markdown(result))]
        written += write_residual_figures(result, design.rest.faces, staged.path)
        with open_recorder(args) as rec:
            if rec is not None:
                rec.log_calibration(result)
        commit(staged, args)
    written = [out / Path(p).name for p in written]
    if args.json:
        data = calibration_data(result, design)
        data["outputs"] = [str(p) for p in written]
        print(json.dumps(data, indent=2, default=lambda o: np.asarray(o).tolist()))
    else:
        _print(result, out, written)
    return 0


def add_calibration_arg(sp, what: str) -> None:
    """``--calibration FILE`` (a calibration.json of ``warp-shape calibrate``) on ``design``, ``control``, ``export``."""
    sp.add_argument("--calibration", default=None, metavar="FILE",
                    help=f"a calibration.json written by warp-shape calibrate: {what}")
