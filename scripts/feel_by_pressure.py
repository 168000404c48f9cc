"""Stiffness against chamber pressure for the shipped designs (docs/feel.md): each scene's design inflated by
air factors, settled (IPAMs at rest, nothing jammed), an 8 mm fingertip pressed 2 mm on the top; the
stiffness and its derivatives by the equilibrium's adjoint (``ws.stiffness_gradient``). Prints a Markdown
table.

    nice -n 10 .venv/bin/python scripts/feel_by_pressure.py [--airs 1.1 1.2 1.3 1.4] [--scenes cube_fig6 oval_heart]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import warp_shape as ws
from warp_shape.io.scene_read import load_scene


def rows(scene: str, airs, depth: float = 0.002) -> list[str]:
    design = load_scene(scene).design
    top_cell = int(design.face_cell()[int(np.argmax(design.rest.face_centroids()[:, 2]))]) if design.n_cells else -1
    out = []
    for air in airs:
        t0 = time.perf_counter()
        sim = ws.Simulator(design, precision="float64")
        sim.air_moles *= air
        sim.settle_static()
        g = ws.stiffness_gradient(sim, (0, 0, 1), depth=depth)
        cell = f"{g.cells[top_cell] / 1e3:.4f}" if top_cell >= 0 else "-"
        out.append(f"| {scene} | {design.rest.n_vertices} | {air:.2f} | {g.pressure:.0f} | {g.force:.4f} | "
                   f"{g.stiffness / 1e3:.4f} | {g.air / 1e3 * sim.model.host.rest_air / 10:.4f} | {cell} | "
                   f"{time.perf_counter() - t0:.1f} |")
        print(out[-1], flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--airs", type=float, nargs="+", default=[1.1, 1.2, 1.3, 1.4])
    ap.add_argument("--scenes", nargs="+", default=["cube_fig6", "oval_heart"])
    args = ap.parse_args()
    print("| design | vertices | air / rest air | gauge pressure, Pa | force at 2 mm, N | stiffness, N/mm | "
          "dk / d air per 0.1 rest air, N/mm | dk / d ln s of the top cell, N/mm | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scene in args.scenes:
        rows(scene, args.airs)


if __name__ == "__main__":
    main()
