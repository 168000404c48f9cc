"""The mold sizes docs/fabrication.md quotes, from a run's molds_<units>.json (e.g. of `make demo`):

    .venv/bin/python scripts/fabrication_sizes.py out/molds_mm.json

prints the paragraph "Sizes for the default problem ..." to paste over the one in the docs, so the
docs quote what a run makes rather than what an older one made."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def sizes_paragraph(data: dict) -> str:
    """The docs' sentence from a ``molds_<units>.json``'s parts and core seat."""
    parts, seat, unit = data["parts"], data["core_seat"], data["units"]
    x = lambda e: " x ".join(f"{v:.1f}" for v in e)  # noqa: E731
    near = len(seat.get("covers_ipam_ends", []))
    return (f"Sizes for the default problem (`make demo`: oval + heart, 4 IPAMs), from `molds_{unit}.json` "
            f"(`scripts/fabrication_sizes.py`): core {x(parts['mold_core']['extents'])} {unit} (the seat's stem "
            f"included: {2 * seat['radius']:.1f} {unit} across, {seat['height']:.1f} {unit} tall"
            + (f", covering {near} IPAM end{'s' if near != 1 else ''}" if near else "") + "), shell halves "
            f"{x(parts['mold_shell_bottom']['extents'])} {unit} (bottom, pins included) and "
            f"{x(parts['mold_shell_top']['extents'])} {unit} (top).")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: fabrication_sizes.py out/molds_mm.json")
    print(sizes_paragraph(json.loads(Path(sys.argv[1]).read_text())))
