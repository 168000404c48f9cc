"""Mesh convergence of the fingertip's stiffness (docs/feel.md, "Mesh"): an 8 mm fingertip pressed 2 mm
into the top of the 4 cm balloon (air 1.3x, held at its 25 degree plug) on icospheres of 642, 2562 and
10242 vertices, with the edge-spring lattice and the neo-Hookean membrane. Prints a markdown table and
writes it with the raw numbers as JSON (atomically). Heavy on a CPU (the 10242-vertex presses): run it
with nice.

    nice -n 10 python scripts/feel_convergence.py [--out feel_convergence.json] [--subdivisions 3 4 5]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import warp_shape as ws


def stiffness(membrane: str, subdivisions: int) -> dict:
    design = ws.Design(ws.icosphere(subdivisions, 0.04), material=ws.Material(membrane=membrane))
    sim = ws.Simulator(design, precision="float64")
    sim.air_moles *= 1.3
    start = time.perf_counter()
    p = ws.press(sim, (0, 0, 1), [0.002])
    return dict(membrane=membrane, vertices=int(design.rest.n_vertices), stiffness=float(p.stiffness[0]),
                force=float(p.force[0]), pressure=float(p.pressure[0]), contact_area=float(p.contact_area[0]),
                surface_penetration=float(p.surface_penetration[0]), seconds=time.perf_counter() - start)


def table(rows: list) -> str:
    lines = ["| membrane | vertices | stiffness at 2 mm (N/m) | change from the coarser | force (N) | pressure (Pa) |",
             "|---|---|---|---|---|---|"]
    last = {}
    for r in rows:
        prev = last.get(r["membrane"])
        change = "" if prev is None else f"{100 * (r['stiffness'] / prev - 1):+.1f} %"
        lines.append(f"| {r['membrane']} | {r['vertices']} | {r['stiffness']:.2f} | {change} | {r['force']:.4f} | "
                     f"{r['pressure']:.0f} |")
        last[r["membrane"]] = r["stiffness"]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="feel_convergence.json")
    ap.add_argument("--subdivisions", type=int, nargs="+", default=[3, 4, 5])
    ap.add_argument("--membranes", nargs="+", default=["springs", "neo_hookean"])
    args = ap.parse_args()
    rows = []
    for membrane in args.membranes:
        for sub in args.subdivisions:
            rows.append(stiffness(membrane, sub))
            print(json.dumps(rows[-1]), flush=True)
    text = table(rows)
    print(text)
    folder = os.path.dirname(os.path.abspath(args.out))
    with tempfile.NamedTemporaryFile("w", dir=folder, delete=False, suffix=".tmp") as f:
        json.dump(dict(rows=rows, table=text), f, indent=1)
    os.replace(f.name, args.out)


if __name__ == "__main__":
    main()
