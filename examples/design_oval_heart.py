"""Design one display for two targets, an oval and a heart (Algorithm 1, section V).

The designer averages the targets into a rest shape, then adds IPAMs with jamming cells one at a
time where the radial error is largest, controlling the device to both targets after each addition.

    python examples/design_oval_heart.py [--actuators 4] [--subdivisions 3] [--codesign off]
"""

import argparse

import warp_shape as ws
from warp_shape.designer.design_settings import CODESIGN_MODES


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--actuators", type=int, default=4)
    parser.add_argument("--subdivisions", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--codesign", default=ws.DesignSettings().codesign, choices=CODESIGN_MODES,
                        help="after placement, optimise the rest shape (and the IPAMs' sizes) by gradient")
    args = parser.parse_args(argv)

    base = ws.icosphere(args.subdivisions, 0.035)
    names = ["oval", "heart"]
    out = ws.design(base, [ws.target(n) for n in names], actuators=args.actuators, target_names=names,
                    device=args.device, codesign=args.codesign)

    print(f"{out.design.n_ipams} IPAMs, {out.design.n_cells} cells on a {out.design.rest.n_vertices}-vertex membrane")
    print("round  " + "  ".join(f"{n:>8}" for n in names) + "   (PCC)")
    for i, row in enumerate(out.pcc_by_round):
        print(f"{i:>5}  " + "  ".join(f"{v:8.4f}" for v in row))
    for name, res in zip(names, out.results):
        print(f"{name}: MARE {res.mare * 1e3:.2f} mm, MPRE {res.mpre:.1f} %")
    return dict(result=out)


if __name__ == "__main__":
    main()
