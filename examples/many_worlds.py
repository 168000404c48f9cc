"""Simulate many copies of one design at once: one batch of worlds, one launch per kernel for all.

Each world inflates the same membrane with a different amount of air; the batch shows the
pressure-volume curve of the device in one run. On a GPU thousands of worlds cost about as much as one.

    python examples/many_worlds.py [--worlds 16] [--device cpu]
"""

import argparse
import time

import numpy as np

import warp_shape as ws


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=16)
    parser.add_argument("--subdivisions", type=int, default=3)
    parser.add_argument("--steps", type=int, default=400, help="1 ms steps to settle")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)

    design = ws.Design(ws.icosphere(args.subdivisions, 0.035), ws.Material())
    sim = ws.Simulator(design, device=args.device, worlds=args.worlds)
    air_scale = np.linspace(1.0, 1.5, args.worlds)  # 1.0 to 1.5x the rest amount of air
    sim.air_moles = sim.air_moles * air_scale

    start = time.perf_counter()
    sim.step(args.steps)
    wall = time.perf_counter() - start

    volume, pressure = sim.volume(), sim.pressure()  # (W,) each
    print(f"{args.worlds} worlds x {design.rest.n_vertices} vertices, {args.steps} steps in {wall:.2f} s")
    print(" air x   volume (cm^3)   gauge pressure (kPa)")
    for a, v, p in zip(air_scale, volume, pressure):
        print(f"{a:5.2f}   {v * 1e6:13.2f}   {p / 1e3:20.3f}")
    return dict(air_scale=air_scale, volume=volume, pressure=pressure, speed=np.abs(sim.velocities).max())


if __name__ == "__main__":
    main()
