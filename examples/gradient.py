"""Take a gradient in the design space: d(fit)/d(rest shape, IPAM sizes, controls) of a replayed sequence.

The paper's law drives the Fig. 6 device to the cube; ``ws.gradient`` replays that sequence open loop
and runs its adjoint back through every step and jam event. A step of the rest shape against the
gradient (a tiny one, along the exact direction) then lowers the replayed objective, as the
first-order prediction says.

    python examples/gradient.py [--subdivisions 2]
"""

import argparse

import numpy as np

import warp_shape as ws
from warp_shape.scenarios import cube_fig6_design


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=2)
    parser.add_argument("--step", type=float, default=2e-5, help="rest-shape step along -gradient, m (largest)")
    args = parser.parse_args(argv)

    design = cube_fig6_design(subdivisions=args.subdivisions)
    cube = ws.target("cube")
    result = ws.control(design, cube, method="paper")
    g = ws.gradient(design, result, cube)
    print(f"replayed objective {g.objective:.5f} over {g.internal_steps} internal steps")
    for name, value in g.values.items():
        print(f"  d objective / d {name}: largest |.| {np.abs(value).max():.3g} ({ws.GRADIENT_PARAMETERS[name]})")

    # a small step of the rest shape against the gradient, the IPAMs and cells where they were
    grad = g.values["rest_positions"]
    move = -grad * (args.step / np.abs(grad).max())
    moved = ws.Design(ws.TriMesh(design.rest.vertices + move, design.rest.faces), design.material)
    for ip in design.ipams:
        moved.add_ipam(ip.face_a, ip.face_b, stiffness=ip.stiffness, area=ip.area, pressure_limits=ip.pressure_limits)
    for cell in design.cells:
        moved.add_cell(cell.faces)
    after = ws.gradient(moved, result, cube, wrt="rest_positions").objective
    predicted = g.objective + float(np.sum(grad * move))
    print(f"after the step: {after:.5f} (first-order prediction {predicted:.5f})")
    return dict(before=g.objective, after=after, predicted=predicted, gradient=g)


if __name__ == "__main__":
    main()
