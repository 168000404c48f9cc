"""Bring your own target: load a mesh file, check it, and design a display for it.

Any closed mesh that trimesh reads (PLY, STL, OBJ, GLB) works if it is star-shaped from its volume
centroid. This script writes an egg to a file first (so it runs anywhere), then loads it like a scan.

    python examples/custom_target.py [--mesh my_shape.stl] [--actuators 2] [--subdivisions 3]
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np

import warp_shape as ws
from warp_shape.designer.design_settings import CODESIGN_MODES


def write_egg(path: Path) -> Path:
    """An egg 7 cm long: a sphere stretched along z, wider at the bottom than at the top."""
    sphere = ws.icosphere(4, 1.0)
    x, y, z = sphere.vertices.T
    scale = 0.028 * (1.0 - 0.18 * z)  # narrower towards +z
    egg = sphere.copy_with(np.stack([x * scale, y * scale, 0.035 * z], axis=1))
    egg.to_trimesh().export(path)
    return path


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=None, help="a mesh file in metres (default: a generated egg)")
    parser.add_argument("--subdivisions", type=int, default=3)
    parser.add_argument("--actuators", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--codesign", default=ws.DesignSettings().codesign, choices=CODESIGN_MODES,
                        help="after placement, optimise the rest shape (and the IPAMs' sizes) by gradient")
    args = parser.parse_args(argv)

    path = Path(args.mesh) if args.mesh else write_egg(Path(tempfile.mkdtemp()) / "egg.ply")
    target = ws.TriMesh.load(path, center=True)  # validated: closed, manifold, outward-wound
    ws.check_star_shaped(target)  # raises ShapeError naming the directions where it is not
    print(f"{path.name}: {target.n_vertices} vertices, volume {target.volume() * 1e6:.1f} cm^3")

    # single-target design: the rest shape follows the target, then IPAMs go where the error is largest
    out = ws.design(ws.icosphere(args.subdivisions, 0.035), [target], actuators=args.actuators,
                    target_names=[path.stem], device=args.device, codesign=args.codesign)
    for i, res in enumerate(out.rounds):
        r = res[0]
        print(f"{i} IPAMs: PCC {r.pcc:.4f}, MARE {r.mare * 1e3:.2f} mm, MPRE {r.mpre:.1f} %")
    return dict(result=out, target=target)


if __name__ == "__main__":
    main()
