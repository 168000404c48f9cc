"""The membrane law measured (docs/membrane.md): one ellipsoid on several meshings of its surface
inflated by the same air ratio (mesh independence), the thin sphere against its law, and a step's
cost with each law.

The meshings are generated here: icosphere levels mapped onto the ellipsoid, a rotated icosphere, the
convex hull of a Fibonacci point set and a near-isotropic point set (points spread evenly by area on a
fine copy of the surface, projected onto the ellipsoid, then their convex hull: an ellipsoid is convex,
so the hull of points on it triangulates its surface). Shapes are compared by radial sampling: the
distance from each settled membrane's volume centroid to its surface along a fixed set of directions.
"""

from __future__ import annotations

import time

import numpy as np
import manifold3d

import warp_shape as ws
from warp_shape.material import GAS_CONSTANT
from warp_shape.physics.membrane import thin_sphere_pressure
from warp_shape.sampling import fibonacci_directions

__all__ = ["ELLIPSOID_AXES", "ellipsoid_meshings", "inflate", "mesh_independence", "thin_sphere_table",
           "step_cost", "LAW_MATERIALS", "radial_fit", "RADIAL_DEGREE"]

#: semi-axes (m) of the ellipsoid of the mesh-independence check: 40 x 32 x 32 mm
ELLIPSOID_AXES = (0.020, 0.016, 0.016)
#: the laws measured, each as Material keywords (Yeoh: C2 and C3 of a stiffening silicone, docs/membrane.md)
#: degree of the polynomial in the direction that stands for a settled membrane's radius (``radial_fit``)
RADIAL_DEGREE = 8
LAW_MATERIALS = {"springs": dict(membrane="springs"), "neo_hookean": dict(membrane="neo_hookean"),
                 "yeoh": dict(membrane="yeoh", yeoh_c2=1.0e3, yeoh_c3=50.0)}


def _onto_ellipsoid(v: np.ndarray, axes=ELLIPSOID_AXES) -> np.ndarray:
    """Points v (n, 3) moved along their rays from the centre onto the ellipsoid's surface."""
    a = np.asarray(axes)
    return v / np.sqrt(((v / a) ** 2).sum(axis=1, keepdims=True))


def _hull(points: np.ndarray) -> ws.TriMesh:
    """The convex hull (manifold3d) of points on the ellipsoid as an outward-wound mesh, its vertices put
    back on the surface in float64."""
    hull = manifold3d.Manifold.hull_points(np.ascontiguousarray(points, dtype=np.float64)).to_mesh()
    v = _onto_ellipsoid(np.asarray(hull.vert_properties, dtype=np.float64)[:, :3])
    return ws.TriMesh(v, np.asarray(hull.tri_verts, dtype=np.int64))


def _even_points(n: int, iterations: int = 60, neighbours: int = 6, step: float = 0.2) -> np.ndarray:
    """n points spread evenly by area over the ellipsoid: the Fibonacci set moved onto it (denser where
    the surface is drawn in), then relaxed by a short-range repulsion between nearest neighbours (each
    pushed away from those closer than 1.3 times the mean neighbour distance), each iteration projected
    back onto the surface. It takes the spread (std / mean) of the triangle areas from 14 % to 12 %."""
    p = _onto_ellipsoid(fibonacci_directions(n))
    for it in range(iterations):
        if it % 10 == 0:  # the neighbours change slowly: found again every 10 iterations
            sq = (p * p).sum(axis=1)
            r2 = sq[:, None] + sq[None, :] - 2.0 * (p @ p.T)
            np.fill_diagonal(r2, np.inf)
            idx = np.argpartition(r2, neighbours, axis=1)[:, :neighbours]
        d = p[:, None, :] - p[idx]  # (n, k, 3) from each neighbour
        near = np.linalg.norm(d, axis=2)
        reach = 1.3 * float(np.mean(near))
        toward = d / near[..., None]
        p = _onto_ellipsoid(p + step * (toward * np.maximum(reach - near, 0.0)[..., None]).sum(axis=1))
    return p


def ellipsoid_meshings(vertices: int = 642) -> dict:
    """{name: TriMesh} meshings of the ellipsoid ``ELLIPSOID_AXES`` with about ``vertices`` vertices each
    (the icosphere's levels: 642 and 2562): icosphere level 3 and 4 mapped along the rays, level 3
    rotated first, a Fibonacci point set's hull and an even (near-isotropic) point set's hull."""
    ico3 = ws.icosphere(3, 1.0)
    rng = np.random.default_rng(7)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    out = {"icosphere 3": ws.TriMesh(_onto_ellipsoid(ico3.vertices), ico3.faces),
           "icosphere 4": ws.TriMesh(_onto_ellipsoid(ws.icosphere(4, 1.0).vertices), ws.icosphere(4, 1.0).faces),
           "icosphere 3 rotated": ws.TriMesh(_onto_ellipsoid(ico3.vertices @ q.T), ico3.faces),
           "Fibonacci hull": _hull(_onto_ellipsoid(fibonacci_directions(vertices))),
           "even-area hull": _hull(_even_points(vertices))}
    return out


def _monomials(u: np.ndarray, degree: int) -> np.ndarray:
    """(n, m) every monomial u_x^i u_y^j u_z^k, i + j + k <= degree, of unit directions u (n, 3)."""
    cols = [u[:, 0] ** i * u[:, 1] ** j * u[:, 2] ** k for i in range(degree + 1) for j in range(degree + 1 - i)
            for k in range(degree + 1 - i - j)]
    return np.stack(cols, axis=1)


def radial_fit(x: np.ndarray, directions: np.ndarray, degree: int = RADIAL_DEGREE):
    """(radii along ``directions`` (n,) m, largest fit residual at the vertices m): the radius of the
    vertices x (V, 3) from their volume centroid as a smooth function of direction (a least-squares
    polynomial of ``degree`` in the direction's components), evaluated along ``directions``. The
    vertices lie on the membrane; its flat triangles lie inside it by up to h^2 / 8 R, which radial
    sampling of the triangles would count as a difference between meshings."""
    u = x / np.linalg.norm(x, axis=1, keepdims=True)
    r = np.linalg.norm(x, axis=1)
    basis = _monomials(u, degree)
    coef = np.linalg.lstsq(basis, r, rcond=None)[0]
    return _monomials(directions, degree) @ coef, float(np.abs(basis @ coef - r).max())


def inflate(mesh: ws.TriMesh, law: str, air_ratio: float, directions: np.ndarray, precision: str = "float64"):
    """(radii along ``directions`` from the volume centroid (n,) m (``radial_fit``), gauge pressure Pa,
    force evaluations, largest fit residual m) of ``mesh`` with the law ``law`` settled statically at
    ``air_ratio`` times its rest air."""
    d = ws.Design(mesh, ws.Material(**LAW_MATERIALS[law]))
    sim = ws.Simulator(d, precision=precision)
    sim.air_moles = air_ratio * sim.air_moles
    eq = sim.settle_static()
    if not eq.converged.all():
        raise RuntimeError(f"the {law} membrane on this mesh did not settle: {eq}")
    x = sim.positions.reshape(-1, 3).astype(np.float64)
    centre = ws.TriMesh(x, mesh.faces, validate=False).centroid()
    radii, residual = radial_fit(x - centre, directions)
    return radii, float(sim.pressure()), int(eq.evaluations[0]), residual


def mesh_independence(laws=("springs", "neo_hookean"), air_ratio: float = 1.6, directions: int = 4000,
                      meshings: dict | None = None) -> list:
    """Rows per law and meshing: the RMS and largest radial distance (mm) of the settled shape from the
    mean shape over the meshings, and the pressure's departure (%) from their mean pressure."""
    meshings = ellipsoid_meshings() if meshings is None else meshings
    dirs = fibonacci_directions(directions)
    rows = []
    for law in laws:
        got = {name: inflate(m, law, air_ratio, dirs) for name, m in meshings.items()}
        mean_r = np.mean([g[0] for g in got.values()], axis=0)
        mean_p = np.mean([g[1] for g in got.values()])
        for name, (r, p, evals, residual) in got.items():
            rows.append(dict(law=law, meshing=name, vertices=meshings[name].n_vertices,
                             rms_mm=1e3 * float(np.sqrt(np.mean((r - mean_r) ** 2))),
                             max_mm=1e3 * float(np.abs(r - mean_r).max()), pressure_Pa=p,
                             pressure_pct=100.0 * (p / mean_p - 1.0), evaluations=evals,
                             fit_residual_mm=1e3 * residual))
    return rows


def thin_sphere_table(laws=("neo_hookean", "yeoh"), stretches=(1.05, 1.2, 7 ** (1 / 6), 1.6, 2.0, 2.5),
                      level: int = 3, radius: float = 0.02) -> list:
    """Rows per law and target stretch: a sphere's static settle at the air of that stretch, its
    stretch and pressure against the thin-sphere law at the stretch reached."""
    rows = []
    for law in laws:
        mat = ws.Material(**LAW_MATERIALS[law])
        d = ws.Design(ws.icosphere(level, radius), mat)
        sim = ws.Simulator(d, precision="float64")
        v0, rt = d.rest.volume(), GAS_CONSTANT * mat.temperature
        for lam in stretches:
            p = thin_sphere_pressure(lam, mat.mu, mat.thickness, radius, mat.yeoh_c2, mat.yeoh_c3)
            sim.positions = d.rest.vertices
            sim.air_moles = (p + mat.atmospheric_pressure) * v0 * lam ** 3 / rt
            eq = sim.settle_static()
            got = (float(sim.volume()) / v0) ** (1 / 3)
            law_p = float(thin_sphere_pressure(got, mat.mu, mat.thickness, radius, mat.yeoh_c2, mat.yeoh_c3))
            rows.append(dict(law=law, stretch=got, pressure_Pa=float(sim.pressure()), law_Pa=law_p,
                             error_pct=100.0 * (float(sim.pressure()) / law_p - 1.0),
                             evaluations=int(eq.evaluations[0])))
    return rows


def step_cost(laws=tuple(LAW_MATERIALS), level: int = 3, steps: int = 200, integrator: str = "rk4",
              precision: str = "float32", device: str | None = None, repeats: int = 3) -> list:
    """Rows per law: the wall time of one internal step (best of ``repeats`` runs of ``steps``) of a
    sphere inflated by 2 % more air, the internal step and the time per simulated second, measured side
    by side in one run: the laws' runs alternate, so a change of the machine's load reaches each alike."""
    sims = {}
    for law in laws:
        d = ws.Design(ws.icosphere(level, 0.04), ws.Material(**LAW_MATERIALS[law]))
        sim = ws.Simulator(d, integrator=integrator, precision=precision, device=device or "cpu")
        sim.air_moles = 1.02 * sim.air_moles
        sim.step(2)  # builds and warms the step
        sims[law] = (d, sim)
    best = dict.fromkeys(laws, np.inf)
    for _ in range(repeats):
        for law, (_, sim) in sims.items():
            t0 = time.perf_counter()
            sim.step(steps)
            best[law] = min(best[law], time.perf_counter() - t0)
    rows = []
    for law, (d, sim) in sims.items():
        internal = best[law] / (steps * sim.substeps)
        rows.append(dict(law=law, integrator=integrator, precision=precision, vertices=d.rest.n_vertices,
                         internal_dt=sim.internal_dt, step_us=1e6 * internal,
                         seconds_per_simulated_second=best[law] / (steps * sim.dt)))
    base = next((r for r in rows if r["law"] == "springs"), None)
    for r in rows:
        r["step_vs_springs"] = r["step_us"] / base["step_us"] if base else float("nan")
        r["time_vs_springs"] = (r["seconds_per_simulated_second"] / base["seconds_per_simulated_second"]
                                if base else float("nan"))
    return rows
