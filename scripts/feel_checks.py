"""The contact checks of docs/feel.md on two meshes (642 and 2562 vertices): a plate pressed 10 mm on a
pure membrane (force against gauge pressure x contact area) and an 8 mm fingertip pressed 0.1 mm on a
pressurised sphere held by its lower hemisphere (stiffness against Vella et al. 2012), and the Fig. 6
device's top pressed free and with its cell jammed (both paths). Prints one JSON line per check.

    nice -n 10 python scripts/feel_checks.py [--subdivisions 3 4]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

import warp_shape as ws
from warp_shape import feel


def plate(subdivisions: int) -> dict:
    design = ws.Design(ws.icosphere(subdivisions, 0.04), material=ws.Material(bending_stiffness=0.0))
    sim = ws.Simulator(design, precision="float64")
    sim.air_moles *= 1.3
    setup, depths = feel.press_setup(sim, 0, (0, 0, 1), "plate", 0.008, [0.005, 0.01, 0.015])
    rows = feel.press_path(setup, depths)
    return dict(check="plate", vertices=int(design.rest.n_vertices), depth=depths.tolist(),
                force=[float(r["force"][0]) for r in rows], pressure=[float(r["pressure"][0]) for r in rows],
                contact_area=[float(r["contact_area"][0]) for r in rows],
                force_over_pA=[float(r["force"][0] / (r["pressure"][0] * r["contact_area"][0])) for r in rows],
                surface_penetration=[float(r["surface_penetration"][0]) for r in rows])


def vella(subdivisions: int) -> dict:
    design = ws.Design(ws.icosphere(subdivisions, 0.04), material=ws.Material(atmospheric_pressure=1000.0))
    sim = ws.Simulator(design, precision="float64")
    sim.air_moles *= 1.8
    sim.settle_static()
    x = sim.positions
    radius = float(np.linalg.norm(x - x.mean(axis=0), axis=1).mean())
    p = ws.press(sim, (0, 0, 1), [1e-4], plug_angle=90)
    mat = design.material
    y, b = mat.youngs_modulus * mat.thickness, mat.bending_stiffness / np.sqrt(3)
    tau = p.pressure[0] * radius ** 2 / (4 * np.sqrt(y * b))
    k = np.pi * p.pressure[0] * radius * np.sqrt(tau ** 2 - 1) / (tau * np.arctanh(np.sqrt(1 - tau ** -2)))
    return dict(check="vella", vertices=int(design.rest.n_vertices), tau=float(tau), stiffness=float(p.stiffness[0]),
                theory=float(k), ratio=float(p.stiffness[0] / k))


def jamming(subdivisions: int) -> dict:
    from warp_shape.scenarios import cube_fig6_design

    design = cube_fig6_design(subdivisions)
    top = int(design.face_cell()[design.ipams[4].face_a])
    sim = ws.Simulator(design, precision="float64")
    sim.air_moles *= 1.3
    free = ws.press(sim, (0, 0, 1), [0.002, 0.003, 0.0], jam={1: [top]})  # press, jam, release
    jammed_sim = ws.Simulator(design, precision="float64")
    jammed_sim.air_moles *= 1.3
    jammed_sim.settle_static()
    jammed_sim.jam(top)
    jammed = ws.press(jammed_sim, (0, 0, 1), [0.002, 0.003, 0.0])  # jam, press, release
    return dict(check="jamming", vertices=int(design.rest.n_vertices), depth=[0.002, 0.003],
                free_stiffness=free.stiffness[:2].tolist(), jammed_stiffness=jammed.stiffness[:2].tolist(),
                free_force=free.force[:2].tolist(), jammed_force=jammed.force[:2].tolist(),
                top_after_release_mm=[float(free.positions[-1][:, 2].max() * 1e3),
                                      float(jammed.positions[-1][:, 2].max() * 1e3)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subdivisions", type=int, nargs="+", default=[3, 4])
    args = ap.parse_args()
    for sub in args.subdivisions:
        for check in (plate, vella, jamming):
            print(json.dumps(check(sub)), flush=True)


if __name__ == "__main__":
    main()
