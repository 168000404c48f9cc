"""Drive the Fig. 6 device to the cube with the paper's controller (section IV-B).

The controller samples the cube radially through the membrane's vertices every control period, then
sets the chamber air (eq. 11), each IPAM's pressure (eq. 12) and jams cells (eqs. 13-15). It reports
the fit: the scaled radial error objective with PCC, MARE and MPRE beside it, and whether an
actuator limit stopped it.

    python examples/control_cube.py [--subdivisions 3] [--max-steps 300]
"""

import argparse

import numpy as np

import warp_shape as ws
from warp_shape.scenarios import cube_fig6_design


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=3)
    parser.add_argument("--max-steps", type=int, default=300, help="control-step limit")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)

    design = cube_fig6_design(subdivisions=args.subdivisions)
    cube = ws.target("cube")
    result = ws.control(design, cube, device=args.device, max_steps=args.max_steps, target_name="cube")

    # the fit of the rest sphere, for scale: radii of the rest shape against the sampled cube
    rest = design.rest.vertices
    r0 = np.linalg.norm(rest, axis=1)
    R0 = np.linalg.norm(ws.radial_sample(cube.centered(), rest), axis=1)
    print(f"rest sphere: MARE {ws.mare(r0, R0) * 1e3:.2f} mm, MPRE {ws.mpre(r0, R0):.1f} %")
    print(f"controlled:  objective {result.objective:.4f}, MARE {result.mare * 1e3:.2f} mm, MPRE {result.mpre:.1f} %, "
          f"PCC {result.pcc:.4f} after {result.control_steps} control steps")
    if result.saturated:
        print("saturated: " + ", ".join(result.saturated))
    print(f"{result.reason}")
    print("final IPAM pressures (kPa): " + " ".join(f"{p / 1e3:.0f}" for p in result.ipam_pressures))
    print(f"cells jammed: {int(result.jammed.sum())} of {len(result.jammed)}")
    return dict(result=result, rest_mare=ws.mare(r0, R0))


if __name__ == "__main__":
    main()
