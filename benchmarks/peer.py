"""Peer benchmark: the same spring + bending membrane in Newton's SolverSemiImplicit, side by side.

Newton is not a dependency of warp_shape; install it next to it (``pip install newton``) to run
this. Both sides step an icosphere membrane with semi-implicit Euler (one force evaluation per
step), capture one step as a Warp graph and replay it, on the same device, in one process.
warp_shape's step also carries what Newton's does not: enclosed volume and pressure forces and
viscous damping, so the comparison is conservative for warp_shape.
"""

from __future__ import annotations

import numpy as np

from warp_shape.display import Design
from warp_shape.material import Material
from warp_shape.mesh import icosphere
from warp_shape.simulator import Simulator

from .common import min_time_per_call

__all__ = ["bench_peer"]


def bench_peer(subdivisions=(3, 4, 5), device: str = "cpu", seconds: float = 0.3, repeats: int = 3) -> list[dict]:
    """Force evaluations per second: warp_shape vs Newton SolverSemiImplicit on the same membrane."""
    try:
        import newton
    except ImportError:
        return [dict(note="Newton is not installed here (pip install newton) - peer bench skipped")]
    import warp as wp

    rows = []
    mat = Material()
    for sub in subdivisions:
        rest = icosphere(sub, 0.04)
        design = Design(rest, mat)
        h = 0.9 * Simulator(design, device=device, integrator="semi_implicit").stable_dt()
        ours = Simulator(design, device=device, integrator="semi_implicit", dt=h, substeps=1)
        ours.positions = rest.vertices * 1.02  # a little stretch so there is work to do
        ours.step(1)  # builds and captures the step
        t_ours = min_time_per_call(lambda: ours.plan.run(1), device, seconds, repeats)

        host = ours.model.host
        builder = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        builder.add_particles(pos=[tuple(p) for p in rest.vertices], vel=[(0.0, 0.0, 0.0)] * rest.n_vertices,
                              mass=list(host.mass), radius=[1e-4] * rest.n_vertices)
        hinges = host.hinges
        for e in range(len(hinges)):
            builder.add_spring(int(hinges[e, 0]), int(hinges[e, 1]), ke=float(host.edge_stiffness[e]),
                               kd=mat.spring_damping, control=0.0)
        # Newton's edge (i, j | k, l): triangles (i, k, l) and (j, l, k); ours: A = (v0, v1, v2), B = (v1, v0, v3)
        builder.add_edges(hinges[:, 2].tolist(), hinges[:, 3].tolist(), hinges[:, 0].tolist(), hinges[:, 1].tolist(),
                          edge_ke=[mat.bending_stiffness] * len(hinges), edge_kd=[0.0] * len(hinges))
        model = builder.finalize(device=device)
        solver = newton.solvers.SolverSemiImplicit(model)
        s0, s1 = model.state(), model.state()
        control = model.control()
        # a little stretch so there is work to do
        s0.particle_q.assign((rest.vertices * 1.02).astype(np.float32))

        def two_steps():  # ping-pong between the states: no copies; Newton accumulates forces, so clear first
            s0.clear_forces()
            solver.step(s0, s1, control, None, h)
            s1.clear_forces()
            solver.step(s1, s0, control, None, h)

        two_steps()  # compile before capture
        with wp.ScopedCapture(device=device, force_module_load=False) as capture:
            two_steps()
        t_newton = min_time_per_call(lambda: wp.capture_launch(capture.graph), device, seconds, repeats) / 2
        moved = float(np.abs(s0.particle_q.numpy() - rest.vertices * 1.02).max())
        if not np.isfinite(moved) or moved > 0.01:
            raise RuntimeError(f"Newton's membrane moved {moved} m: the peer setup is wrong")
        rows.append(dict(vertices=rest.n_vertices, edges=len(hinges), device=str(ours.device),
                         warp_shape_evals_per_s=round(1.0 / t_ours, 1), newton_evals_per_s=round(1.0 / t_newton, 1),
                         ratio=round(t_newton / t_ours, 2), newton_version=getattr(newton, "__version__", "?")))
    return rows
