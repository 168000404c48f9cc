"""Inflate the paper's Fig. 6 device, jam its cells and pressurise its IPAMs.

A 642-vertex silicone sphere holds five IPAMs: four join opposite cube-corner directions, one joins
the +z and -z poles; a jamming cell surrounds every IPAM end. The script inflates the chamber,
freezes the cells, then drives the corner IPAMs to push and the pole IPAM to pull (section IV-C).

    python examples/inflate_fig6.py [--subdivisions 3] [--device cpu]
"""

import argparse

import numpy as np

import warp_shape as ws


def build_device(subdivisions: int, radius: float = 0.035, cell_radius: float = 0.012) -> ws.Design:
    rest = ws.icosphere(subdivisions, radius)
    design = ws.Design(rest, ws.Material())
    centroids = rest.face_centroids()
    unit = centroids / np.linalg.norm(centroids, axis=1, keepdims=True)

    def face_towards(direction):
        return int(np.argmax(unit @ (direction / np.linalg.norm(direction))))

    corners = [(1, 1, 1), (1, -1, 1), (-1, 1, 1), (-1, -1, 1), (0, 0, 1)]
    for c in corners:
        d = np.array(c, dtype=float)
        design.add_ipam(face_towards(d), face_towards(-d))
    # a jamming cell of faces within cell_radius around each IPAM end
    for ip in design.ipams:
        for end in (ip.face_a, ip.face_b):
            near = np.linalg.norm(centroids - centroids[end], axis=1) < cell_radius
            design.add_cell(np.flatnonzero(near & (design.face_cell() < 0)))
    return design


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)

    design = build_device(args.subdivisions)
    sim = ws.Simulator(design, device=args.device)  # RK4, float32, dt = 1 ms, automatic substeps
    rest_volume = sim.volume()

    # 1. inflate: the amount of air is the control; ramp it to 1.6x the rest amount over 0.3 s
    air0 = sim.air_moles
    for k in range(1, 31):
        sim.air_moles = air0 * (1.0 + 0.6 * k / 30)
        sim.step(10)
    inflated_volume, inflated_pressure = sim.volume(), sim.pressure()

    # 2. jam every cell: their edges freeze at today's shape and stiffen (x10 stretch, x30 bending)
    for cell in range(design.n_cells):
        sim.jam(cell)

    # 3. corner IPAMs push (pressurised: longer natural length), the pole IPAM pulls (vented)
    target = np.array([150e3, 150e3, 150e3, 150e3, -20e3])
    for k in range(1, 31):
        sim.ipam_pressures = target * k / 30
        sim.step(10)

    forces = sim.ipam_forces()
    print(f"{design.rest.n_vertices} vertices, {design.n_ipams} IPAMs, {design.n_cells} cells; "
          f"{sim.substeps} internal steps per {sim.dt * 1e3:g} ms step")
    print(f"rest volume {rest_volume * 1e6:.1f} cm^3 -> inflated {inflated_volume * 1e6:.1f} cm^3 "
          f"at {inflated_pressure / 1e3:.2f} kPa gauge")
    print("IPAM axial forces (N, + = tension): " + " ".join(f"{f:+.3f}" for f in forces))
    return dict(rest_volume=rest_volume, inflated_volume=inflated_volume, pressure=inflated_pressure,
                ipam_forces=forces, jammed=sim.jammed)


if __name__ == "__main__":
    main()
