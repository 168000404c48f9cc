"""Write the shipped scenes to scenes/<name>.usda (the definitions below are the source of truth).

Targets (one design-less scene per target, the target at the default volume and resolution):
    target_oval, target_pear, target_heart, target_cube
Design problems (each refers to the target scenes above by a USD reference, so they stay small):
    cube_fig6        Fig. 6: sphere with 5 IPAMs and 10 cells (scenarios.cube_fig6_design), target cube
    oval_heart       Fig. 13 / section V-D: icosphere(3, 0.035 m) base, targets oval and heart,
                     designer: 4 actuators, 16 mm cell radius
    four_targets_5   Fig. 11: base sphere, all four targets, designer: 5 actuators, 12 mm cells
    four_targets_20  Fig. 12: base sphere, all four targets, designer: 20 actuators, 6 mm cells
                     (cell radius halved: a quarter of the area)

    python scripts/make_scenes.py [--out scenes] [--check]

``--check`` writes into a temporary directory and exits 1 if any shipped file differs.
"""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from pathlib import Path

from warp_shape.display import Design
from warp_shape.material import Material
from warp_shape.mesh import icosphere
from warp_shape.scenarios import cube_fig6_design
from warp_shape.simulation_settings import SimulationSettings
from warp_shape.io.scene_schema import Scene
from warp_shape.io.scene_write import save_scene
from warp_shape.targets import TARGET_NAMES, target

BASE_SUBDIVISIONS = 3
BASE_RADIUS = 0.035  # m
#: the simulation settings a problem scene states (the defaults of SimulationSettings)
SIMULATION_KEYS = ("integrator", "dt", "precision", "bending")


def _base_design() -> Design:
    return Design(icosphere(BASE_SUBDIVISIONS, BASE_RADIUS), Material())


def _problem(design: Design, names, designer: dict | None = None) -> Scene:
    defaults = SimulationSettings().to_dict()
    settings = {"simulation": {k: defaults[k] for k in SIMULATION_KEYS}}
    if designer:
        settings["designer"] = dict(designer)
    return Scene(design=design, targets=[target(n) for n in names], target_names=list(names), settings=settings)


def scene_definitions() -> dict:
    """name -> (Scene, target_references) for every shipped scene, in writing order."""
    out = {}
    for name in TARGET_NAMES:
        out[f"target_{name}"] = (Scene(targets=[target(name)], target_names=[name]), None)

    def refs(names):
        return {n: f"./target_{n}.usda" for n in names}

    out["cube_fig6"] = (_problem(cube_fig6_design(), ["cube"]), refs(["cube"]))
    two = ["oval", "heart"]
    out["oval_heart"] = (_problem(_base_design(), two, {"actuators": 4, "cell_radius": 0.016}), refs(two))
    four = list(TARGET_NAMES)
    out["four_targets_5"] = (_problem(_base_design(), four, {"actuators": 5, "cell_radius": 0.012}), refs(four))
    out["four_targets_20"] = (_problem(_base_design(), four, {"actuators": 20, "cell_radius": 0.006}), refs(four))
    return out


def write_scenes(directory) -> list[Path]:
    """Write every shipped scene into ``directory``; return the paths."""
    directory = Path(directory)
    paths = []
    for name, (scene, refs) in scene_definitions().items():
        paths.append(save_scene(scene, directory / f"{name}.usda", target_references=refs))
    return paths


def main(argv=None) -> int:
    root = Path(__file__).resolve().parents[1]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(root / "scenes"))
    ap.add_argument("--check", action="store_true", help="compare with the files in --out instead of writing")
    args = ap.parse_args(argv)
    if args.check:
        with tempfile.TemporaryDirectory() as tmp:
            stale = [p.name for p in write_scenes(tmp)
                     if not (Path(args.out) / p.name).exists() or not filecmp.cmp(p, Path(args.out) / p.name, shallow=False)]
        if stale:
            print(f"out of date: {', '.join(stale)} (run python scripts/make_scenes.py)", file=sys.stderr)
            return 1
        print("shipped scenes are up to date")
        return 0
    for path in write_scenes(args.out):
        print(f"{path}: {path.stat().st_size / 1024:.0f} KiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
