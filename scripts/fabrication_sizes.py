"""The numbers docs/fabrication.md quotes about a run (the mold sizes, the valve sequences' lengths),
from the run's files (e.g. `make demo`'s out/):

    .venv/bin/python scripts/fabrication_sizes.py out

prints the two sentences to paste over those in the docs, so the docs quote what a run makes rather
than what an older one made."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def sizes_paragraph(data: dict) -> str:
    """The mold sizes from a ``molds_<units>.json``'s parts and core seat."""
    parts, seat, unit = data["parts"], data["core_seat"], data["units"]
    x = lambda e: " x ".join(f"{v:.1f}" for v in e)  # noqa: E731
    near = len(seat.get("covers_ipam_ends", []))
    return (f"Sizes for the default problem (`make demo`: oval + heart, 4 IPAMs), from `molds_{unit}.json` "
            f"(`scripts/fabrication_sizes.py`): core {x(parts['mold_core']['extents'])} {unit} (the seat's stem "
            f"included: {2 * seat['radius']:.1f} {unit} across, {seat['height']:.1f} {unit} tall"
            + (f", covering {near} IPAM end{'s' if near != 1 else ''}" if near else "") + "), shell halves "
            f"{x(parts['mold_shell_bottom']['extents'])} {unit} (bottom, pins included) and "
            f"{x(parts['mold_shell_top']['extents'])} {unit} (top).")


def valve_paragraph(sidecars: dict) -> str:
    """The valve sequences' lengths from the ``valve_<target>.json`` sidecars ({target: content})."""
    names = list(sidecars)
    sim = ", ".join(f"{sidecars[n]['simulated_duration_s']:.2f}" for n in names)
    take = " and ".join(f"{s['duration_s']:.1f} s ({n}, {s['rows']} rows)" for n, s in sidecars.items())
    flow = ", ".join(f"{s['peak']['flow_ml_s']:.2f}" for s in sidecars.values())
    slew = " / ".join(f"{s['peak']['slew_kpa_s']:.1f}" for s in sidecars.values())
    return (f"The default demo's sequences ({sim} s simulated) take {take} at 5 mL/s, 100 kPa/s and 50 Hz "
            f"(`scripts/fabrication_sizes.py`); the sidecars' `peak` gives {flow} mL/s and {slew} kPa/s.")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: fabrication_sizes.py RUN_FOLDER (e.g. out)")
    run = Path(sys.argv[1])
    print(sizes_paragraph(json.loads(next(run.glob("molds_*.json")).read_text())))
    print()
    print(valve_paragraph({p.stem[len("valve_"):]: json.loads(p.read_text()) for p in sorted(run.glob("valve_*.json"))}))
