"""The differentiable replay's forward against the simulator, on the default problem's sequences.

Designs the default problem (oval + heart, 4 IPAMs; ``--codesign off`` by default to save time), then
for each target replays its control sequence in float64 three ways: the simulator (``ws.replay`` on
the result with float64 settings), the differentiable replay's forward (``plan_replay``: the same
simulator, keeping the adjoint's checkpoints) and the differentiable replay's own backward-enabled
kernels (``DifferentiableReplay.positions``), and prints the largest vertex distance between them and
the replayed objective beside the one ``ws.gradient`` reports.

    python scripts/replay_identity.py [--codesign rest+ipams]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import warp_shape as ws
from warp_shape.gradients import DifferentiableReplay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--codesign", default="off")
    args = parser.parse_args()
    scene = ws.load_scene("oval_heart")
    out = ws.design(scene.design.rest, scene.targets, actuators=4, codesign=args.codesign)
    for name, res in zip(("oval", "heart"), out.results):
        settings = dataclasses.replace(res.settings, simulation=res.settings.simulation.replace(precision="float64"))
        res64 = dataclasses.replace(res, settings=settings)
        sim = ws.replay(out.design, res64)
        replay = DifferentiableReplay(out.design, res64, precision="float64")
        plan = replay.forward()
        kernels = replay.positions()
        g = ws.gradient(out.design, res64, wrt=("air",))
        print(f"{name}: {plan.internal_steps} internal steps; |plan - simulator| max {np.abs(plan.final - sim).max():.3g} m; "
              f"|kernels - simulator| max {np.abs(kernels - sim).max():.3g} m; objective {g.objective:.10g}")


if __name__ == "__main__":
    main()
