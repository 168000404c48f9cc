"""Write the paper's four target shapes to scenes/targets/<name>.ply.

The generator in ``warp_shape.targets`` is the source of truth; these files are snapshots of it
at the default volume and resolution, for viewing and for tools outside Python.

    python scripts/make_targets.py [--out scenes/targets] [--format ply|obj|stl] [--resolution 4]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from warp_shape.targets import DEFAULT_RESOLUTION, target, write_targets


def main(argv=None) -> int:
    root = Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(root / "scenes" / "targets"))
    ap.add_argument("--format", default="ply", choices=("ply", "obj", "stl"))
    ap.add_argument("--resolution", type=int, default=DEFAULT_RESOLUTION)
    args = ap.parse_args(argv)
    for path in write_targets(args.out, fmt=args.format, resolution=args.resolution):
        m = target(path.stem, resolution=args.resolution)
        print(f"{path}: {m.n_vertices} vertices, {m.n_faces} faces, volume {m.volume():.4e} m^3")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
