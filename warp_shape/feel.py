"""What the hand feels: a rigid frictionless indenter pressed quasi-statically into the display.

``press`` moves a fingertip (a sphere) or a palm (a plate) along -direction onto the surface point
that direction hits from the shape's centroid, then to each depth in turn, settling the membrane
statically at every step (``Simulator.settle_static``: the minimum of the potential energy with the
indenter's depth held as a control, ``physics.contact``); ``stiffness_map`` presses many points of
one state at once, one press per world. The device is held at its plug: the vertices of the faces
around the -z pole (within ``PLUG_ANGLE`` of -z, seen from the centroid) are tied to where they are by
stiff zero-length springs (the "hold" family). docs/feel.md describes the model and its limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .controller.open_loop import replay_simulator
from .controller.result import ControlResult
from .errors import DesignError, SimulationError
from .gradients.equilibrium import EquilibriumGradient
from .physics.contact import (DEFAULT_CONTACT_STIFFNESS, DEFAULT_RADIUS, KINDS, add_hold, add_indenter,
                              closest_weights_np, face_contact_np, indenter_force_one,
                              set_indenter_stiffness, surface_penetration_np)
from .simulator import Simulator

__all__ = ["Press", "press", "stiffness_map", "FeelMap", "feel_map", "pressable_directions", "press_setup",
           "StiffnessGradient", "stiffness_gradient", "contact_force_gradient",
           "press_path", "vertex_areas", "plug_vertices",
           "surface_point", "PLUG_ANGLE",
           "MAX_INCREMENT", "STIFFNESS_STEP", "HOLD_STIFFNESS_FACTOR"]

#: faces whose centroid lies within this angle of -z, seen from the shape's centroid, form the held plug (rad)
PLUG_ANGLE = np.radians(25.0)
#: the largest depth change between two settles of a press, m
MAX_INCREMENT = 1.0e-3
#: depth step of the central difference giving the stiffness dF/d depth, m
STIFFNESS_STEP = 2.0e-5
#: the hold's spring per vertex, in units of the membrane's largest edge stiffness
HOLD_STIFFNESS_FACTOR = 1.0e3
#: the contact's stiffness in the first settle of each depth, as a fraction of its own
SOFT_CONTACT = 0.05
#: the residual vertex force (N) the softened first settle stops at: it only slides the membrane to its place
#: (the full-stiffness settle after it converges to the precision's tolerance); 16 % fewer force evaluations
#: than 1e-7 on a map of the Fig. 6 device (docs/feel.md)
SOFT_TOLERANCE = 1.0e-5
#: a press's settle leaving a larger residual vertex force than this (N) is an error
RESIDUAL_LIMIT = 1.0e-4
#: fresh starts of a settle left above ``RESIDUAL_LIMIT`` before a press gives up
RESTARTS = 12
#: the contact penalty must be at least this many times the membrane's stiffness per edge
PENALTY_MARGIN = 100.0
#: the residual vertex force (N) of the settles whose derivatives ``stiffness_gradient`` takes
EQUILIBRIUM_TOLERANCE = 1.0e-10
#: a vertex deeper than this (m) inside a plate counts as touching it (contact area)
CONTACT_DEPTH = 1.0e-9
#: bisection steps placing a fingertip's first touch of the surface
TOUCH_BISECTIONS = 60


@dataclass
class Press:
    """A press: per depth (n,) the ``depth`` (m from first touch), ``force`` (N, along the press),
    ``stiffness`` (N/m, dF/d depth), gauge ``pressure`` (Pa), ``contact_area`` (m^2, projected on the
    direction: the faces in contact weighted by their touching fraction, the contact line placed on each
    edge leaving the contact where the membrane, departing tangentially, meets the indenter:
    ``contact_area``), ``penetration`` (m, the deepest vertex inside the indenter), ``surface_penetration``
    (m, the deepest point of any face inside it), ``stored_energy`` (J: springs, bending, gas free energy, actuators, contact and hold)
    and ``positions`` (n, V, 3) m; ``point`` (3,) the surface point pressed, ``direction`` (3,),
    ``held`` the plug's vertices."""

    depth: np.ndarray
    force: np.ndarray
    stiffness: np.ndarray
    pressure: np.ndarray
    contact_area: np.ndarray
    penetration: np.ndarray
    surface_penetration: np.ndarray
    stored_energy: np.ndarray
    positions: np.ndarray
    point: np.ndarray
    direction: np.ndarray
    indenter: str
    radius: float
    held: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    jammed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


# ---------------------------------------------------------------------- geometry
def plug_vertices(x: np.ndarray, faces: np.ndarray, angle: float | None = None) -> np.ndarray:
    """The vertices of the faces whose centroid lies within ``angle`` (rad; None: ``PLUG_ANGLE``) of -z seen
    from the centroid of x."""
    angle = PLUG_ANGLE if angle is None else angle
    c = x[faces].mean(axis=1) - x.mean(axis=0)
    cos = -c[:, 2] / np.maximum(np.linalg.norm(c, axis=1), 1e-300)
    return np.unique(faces[cos >= np.cos(angle)].reshape(-1))


def surface_point(x: np.ndarray, faces: np.ndarray, origin: np.ndarray, u: np.ndarray):
    """(point, face) where the ray origin + t u (t > 0) first leaves through the surface, or None."""
    a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    e1, e2 = b - a, c - a
    p = np.cross(u, e2)
    det = np.einsum("fi,fi->f", e1, p)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - a
    bu = np.einsum("fi,fi->f", s, p) * inv
    q = np.cross(s, e1)
    bv = (q @ u) * inv
    t = np.einsum("fi,fi->f", e2, q) * inv
    hit = ok & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 0)
    if not hit.any():
        return None
    f = int(np.flatnonzero(hit)[np.argmax(t[hit])])  # the outermost crossing: the surface a finger meets
    return origin + t[f] * u, f


def first_touch(x: np.ndarray, faces: np.ndarray, point: np.ndarray, u: np.ndarray, kind: str,
                radius: float) -> np.ndarray:
    """The indenter's reference point at depth 0: where, coming from outside along -u through ``point``,
    it first touches the surface x (faces) (the sphere's centre, or a point of the plate's plane)."""
    w = x - point
    a = w @ u
    if kind == "plate":
        return point + float(a.max()) * u
    tri = [x[faces[:, k]] for k in range(3)]

    def inside(t):  # whether the sphere centred at point + t u reaches into a face
        c = point + t * u
        b = closest_weights_np(c[None], *tri)
        q = b[:, 0:1] * tri[0] + b[:, 1:2] * tri[1] + b[:, 2:3] * tri[2]
        return float(np.min(np.linalg.norm(q - c, axis=1))) < radius

    lo, hi = 0.0, float(a.max()) + radius  # centred on the point, the sphere reaches its face; at hi, no face
    for _ in range(TOUCH_BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) else (lo, mid)
    return point + hi * u


# ---------------------------------------------------------------------- the press simulator
def source_simulator(sim_or_result, world: int) -> Simulator:
    """The simulator holding the state to press: ``sim_or_result`` itself, or a control result's final
    state replayed on its design."""
    if isinstance(sim_or_result, ControlResult):
        if sim_or_result.design is None:
            raise DesignError("press needs a control result that carries its design (ws.control returns one)")
        return replay_simulator(sim_or_result.design, [sim_or_result])
    if not isinstance(sim_or_result, Simulator):
        raise DesignError(f"press needs a ws.Simulator or a control result, got {type(sim_or_result).__name__}")
    if isinstance(world, (bool, np.bool_)) or not isinstance(world, (int, np.integer)) \
            or not 0 <= world < sim_or_result.worlds:
        raise DesignError(f"world must be an index in 0..{sim_or_result.worlds - 1}, got {world!r}")
    return sim_or_result


def copy_world_state(src: Simulator, world: int, dst: Simulator) -> None:
    """World ``world`` of ``src`` (positions, air, every actuator family's controls and masks, the jam
    fields and cell masks) into every world of ``dst``, a simulator of the same design with more families."""
    W = dst.worlds

    def every(a):
        return np.broadcast_to(np.asarray(a)[world], (W,) + np.asarray(a).shape[1:]).copy()

    dst.positions = every(src.state.x.numpy().astype(np.float64))
    dst.air_moles = every(src.control.air.numpy().reshape(src.worlds))
    for fam in src.model.families:
        n = src.model.host.count(fam.name)
        if n:
            dst.control.values[fam.name].assign(every(src.control.values[fam.name].numpy()))
            dst.control.enabled[fam.name].assign(every(src.control.enabled[fam.name].numpy()))
    edge = src.state.edge.numpy()[:, world]
    wp.copy(dst.state.edge, wp.array(np.broadcast_to(edge[:, None], (4, W) + edge.shape[1:]).astype(
        dst.model.np_dtype), dtype=dst.model.scalar, device=dst.device))
    dst.state.jammed.assign(every(src.state.jammed.numpy()))
    dst.state.cell_enabled[:] = every(src.state.cell_enabled)
    dst.state.cell_jammed[:] = every(src.state.cell_jammed)
    dst.state.cell_jam_time[:] = every(src.state.cell_jam_time)


@dataclass
class PressSetup:
    """A press simulator (one indenter per world, the plug held) and what each world presses."""

    sim: Simulator
    points: np.ndarray  # (m, 3) surface points pressed
    directions: np.ndarray  # (m, 3) unit
    held: np.ndarray  # plug vertices
    limit: np.ndarray  # (m,) the deepest press allowed, m


def check_directions(directions) -> np.ndarray:
    """(m, 3) unit directions, or a one-line error."""
    try:
        u = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise DesignError(f"a press direction is a 3-vector (or an (m, 3) array), got {directions!r}") from None
    n = np.linalg.norm(u, axis=1)
    if not u.size or not np.all(np.isfinite(u)) or np.any(n <= 0):
        raise DesignError(f"press directions must be finite non-zero 3-vectors, got {u.tolist()}")
    return u / n[:, None]


def settled_copy(src: Simulator, world: int) -> Simulator:
    """A float64 one-world simulator of ``src``'s design holding ``src``'s world ``world`` settled
    statically at its controls and jam state (the state a press starts from)."""
    sim = Simulator(src.design.replace(), device=src.device,
                    settings=src.settings.replace(precision="float64", bending="exact"), worlds=1)
    copy_world_state(src, world, sim)
    sim.settle_static()
    return sim


def touches_plug(x: np.ndarray, held: np.ndarray, point: np.ndarray, reach: float) -> bool:
    """Whether a held vertex of x lies within ``reach`` (m) of ``point``."""
    return bool(held.size) and float(np.min(np.linalg.norm(x[held] - point, axis=1))) < reach


def press_geometry(x: np.ndarray, faces: np.ndarray, u: np.ndarray, held: np.ndarray, reach: float = 0.0):
    """(points (m, 3), limits (m,)): where each direction (m, 3) from the centroid of x meets the surface,
    and the deepest press allowed there (80 % of the shape's extent behind that point), or a one-line error
    (a point with a held vertex within ``reach`` m is on the plug)."""
    points, limits = [], []
    for d in u:
        hit = surface_point(x, faces, x.mean(axis=0), d)
        if hit is None:
            raise DesignError(f"direction {d.round(4).tolist()} from the centroid misses the shape (it is not "
                              "star-shaped there); press another direction")
        if touches_plug(x, held, hit[0], reach):
            raise DesignError(f"direction {d.round(4).tolist()} presses on the held plug (a held vertex within "
                              f"{reach * 1e3:.3g} mm of the point; the plug is the faces within "
                              f"{np.degrees(PLUG_ANGLE):.0f} deg of -z); press another direction")
        points.append(hit[0])
        limits.append(0.8 * float(np.max((hit[0] - x) @ d)))
    return np.asarray(points), np.asarray(limits)


def check_depths(depths, limits: np.ndarray) -> np.ndarray:
    """(n,) depths in m, finite, >= 0 and within every press's limit, or a one-line error."""
    try:
        a = np.asarray(depths, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise DesignError(f"depths must be numbers in m, got {depths!r}") from None
    if not a.size or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise DesignError(f"depths must be finite and >= 0 m (from first touch), got {a.tolist()}")
    if a.max() > limits.min():
        raise DesignError(f"depth {a.max():.4g} m goes beyond the shape: at most {limits.min():.4g} m (80 % of its "
                          "extent behind the point pressed) can be pressed there")
    return a


def check_plug_angle(angle) -> float:
    """The plug's angle in degrees, in (0, 90], or a one-line error."""
    if isinstance(angle, (bool, np.bool_)) or not isinstance(angle, (int, float, np.floating, np.integer)) \
            or not 0 < angle <= 90:
        raise DesignError(f"plug_angle is the held cap's half-angle around -z in degrees, in (0, 90], got {angle!r}")
    return float(angle)


def membrane_stiffness(src: Simulator) -> float:
    """The membrane's largest stiffness per vertex or edge, N/m: its edge springs', or with a hyperelastic
    membrane (whose edge springs carry no elastic force) its triangles' equivalent edge springs (their sum
    at a vertex over its six edges)."""
    host = src.model.host
    k = float(np.max(host.edge_stiffness, initial=0.0))
    membrane = host.actuators.get("membrane") or {}
    return max(k, float(np.max(membrane.get("vertex_stiffness", 0.0), initial=0.0)) / 6.0)


def check_contact_stiffness(src: Simulator, world: int, stiffness: float) -> None:
    """Refuses, with a one-line error, a contact penalty ``stiffness`` (N/m) less than ``PENALTY_MARGIN``
    times the membrane's stiffness (``membrane_stiffness``, times the jam factor where a cell of world
    ``world`` is jammed): the penalty would no longer be the stiff one, its penetration no longer small."""
    k = membrane_stiffness(src)
    if np.any(np.asarray(src.state.cell_jammed)[world]):
        k *= src.design.material.jam_stretch_factor
    if not (np.isfinite(stiffness) and stiffness > 0):
        raise DesignError(f"the contact stiffness must be a finite number > 0 N/m, got {stiffness!r}")
    if stiffness < PENALTY_MARGIN * k:
        raise DesignError(f"the membrane is too stiff for the contact's penalty: up to {k:.3g} N/m per edge (jammed "
                          f"cells included) against {stiffness:.3g} N/m; press with stiffness >= "
                          f"{PENALTY_MARGIN * k:.3g} N/m (and expect shorter settles) or a softer membrane")


def press_setup(src: Simulator, world: int, directions, indenter: str, radius: float, depths,
                stiffness: float = DEFAULT_CONTACT_STIFFNESS, plug_angle: float | None = None) -> PressSetup:
    """Check the press (directions, depths, indenter) on ``src``'s world ``world``, settle it (controls
    held), find each direction's surface point and first touch, and build the press simulator: ``src``'s
    design with one indenter per direction (enabled in its own world only) and the plug held, in float64,
    every world a copy of the settled state; ``plug_angle`` (degrees, None: ``PLUG_ANGLE``) the plug's
    extent around -z. Returns the setup and the checked depths."""
    angle = None if plug_angle is None else np.radians(check_plug_angle(plug_angle))
    if indenter not in KINDS:
        raise DesignError(f"indenter must be one of {sorted(KINDS)}, got {indenter!r}")
    if not (isinstance(radius, (int, float, np.floating)) and np.isfinite(radius) and radius > 0):
        raise DesignError(f"the indenter's radius must be > 0 m, got {radius!r}")
    u = check_directions(directions)
    faces = src.design.rest.faces
    x = np.asarray(src.state.x.numpy()[world], dtype=np.float64)
    reach = 1.5 * radius if indenter == "sphere" else 0.0
    check_depths(depths, press_geometry(x, faces, u, plug_vertices(x, faces, angle), reach)[1])  # before any work
    check_contact_stiffness(src, world, stiffness)
    settled = settled_copy(src, world)
    x = settled.positions.reshape(-1, 3)
    held = plug_vertices(x, faces, angle)
    points, limits = press_geometry(x, faces, u, held, reach)
    depths = check_depths(depths, limits)
    design = src.design.replace()
    for w, (d, p) in enumerate(zip(u, points)):
        add_indenter(design, indenter, d, first_touch(x, faces, p, d, indenter, radius), radius, stiffness, world=w)
    add_hold(design, held, x[held], HOLD_STIFFNESS_FACTOR * membrane_stiffness(src))
    sim = Simulator(design, device=src.device, settings=settled.settings, worlds=len(u))
    copy_world_state(settled, 0, sim)
    sim.set_actuator_mask("indenter", np.eye(len(u), dtype=bool))
    sim.set_actuator_controls("indenter", np.zeros((len(u), len(u))))
    return PressSetup(sim, points, u, held, limits), depths


# ---------------------------------------------------------------------- pressing
def vertex_areas(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(W, V, 3) each vertex's share of the outward area vectors of its faces (a third of each), m^2."""
    a = 0.5 * np.cross(x[:, faces[:, 1]] - x[:, faces[:, 0]], x[:, faces[:, 2]] - x[:, faces[:, 0]])
    out = np.zeros_like(x)
    for k in range(3):
        np.add.at(out, (slice(None), faces[:, k]), a / 3.0)
    return out


def vertex_gaps(host: dict, j: int, x: np.ndarray, depth: float):
    """(gap (V,), gradient (V, 3)): each vertex's distance outside indenter j at ``depth`` (m; < 0 inside)
    and the gap's gradient (the indenter's outward normal there)."""
    c = host["origin"][j] - depth * host["axis"][j]
    if host["kind"][j] == KINDS["plate"]:
        return (c - x) @ host["axis"][j], np.broadcast_to(-host["axis"][j], x.shape)
    d = x - c
    r = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
    return r - host["radius"][j], d / r[:, None]


def touching_vertices(host: dict, j: int, x: np.ndarray, faces: np.ndarray, depth: float, gap: np.ndarray):
    """(V,) bool: the vertices in contact with indenter j. On a plate: deeper than ``CONTACT_DEPTH``. On a
    sphere (it acts on faces, whose chords sag into it): those of a face reaching into it lying within
    the sagitta L^2 / 8R of their longest edge of its surface."""
    if host["kind"][j] == KINDS["plate"]:
        return gap < -CONTACT_DEPTH
    pen = face_contact_np(host, j, x[None], np.array([depth]))[2][0]
    near = np.zeros(len(x), dtype=bool)
    near[faces[pen > 0].reshape(-1)] = True
    longest = np.zeros(len(x))
    for k in range(3):
        edge = np.linalg.norm(x[faces[:, (k + 1) % 3]] - x[faces[:, k]], axis=1)
        np.maximum.at(longest, faces[:, k], edge)
        np.maximum.at(longest, faces[:, (k + 1) % 3], edge)
    return near & (gap <= longest ** 2 / (8 * host["radius"][j]))


def contact_area(host: dict, j: int, x: np.ndarray, faces: np.ndarray, depth: float, u: np.ndarray) -> float:
    """The contact area of indenter j at ``depth`` on the surface x (V, 3), m^2, projected on u: the faces
    in contact weighted by their touching fraction. A face whose vertices all touch counts whole; on a face
    with free vertices, each edge from a touching vertex a to a free one b (length L) is cut where the
    membrane, leaving the indenter tangentially, meets it: the gap grows as kappa (s - s0)^2 / 2 beyond the
    contact line s0, so with b's gap g and the slope sigma of the gap over b's free faces (their secant,
    kappa (L - s0 + L / 2)), L - s0 = g / sigma + sqrt((g / sigma)^2 + L g / sigma). The cut face keeps
    1 - (1 - t1)(1 - t2) (two touching vertices) or t1 t2 (one) of its area (t = s0 / L). A face reaching
    into a sphere counts whole (a fingertip rests on few faces where the edges are not well below the
    contact's radius sqrt(2 R depth): its contact area is then the mesh's, an upper estimate)."""
    gap, grad = vertex_gaps(host, j, x, depth)
    touch = touching_vertices(host, j, x, faces, depth, gap)
    fa = 0.5 * np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    t_face = touch[faces]
    free_faces = ~t_face.any(axis=1)
    normal = np.zeros_like(x)
    for k in range(3):
        np.add.at(normal, faces[free_faces, k], fa[free_faces])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)

    def cut(a, b):  # (m,) the touching fraction t of edges a (touching) -> b (free)
        e = x[b] - x[a]
        length = np.linalg.norm(e, axis=1)
        n = normal[b]
        et = e - np.einsum("mi,mi->m", e, n)[:, None] * n
        et /= np.maximum(np.linalg.norm(et, axis=1, keepdims=True), 1e-300)
        slope = np.einsum("mi,mi->m", grad[b] - np.einsum("mi,mi->m", grad[b], n)[:, None] * n, et)
        q = np.where(slope > 0, np.maximum(gap[b], 0.0) / np.where(slope > 0, slope, 1.0), np.inf)
        return np.clip(1.0 - (q + np.sqrt(q * q + length * q)) / np.maximum(length, 1e-300), 0.0, 1.0)

    frac = t_face.all(axis=1).astype(np.float64)
    count = t_face.sum(axis=1)
    for k in range(3):  # rotate each face so that its odd vertex (the free one of two touching, the touching
        a0, a1, a2 = faces[:, k], faces[:, (k + 1) % 3], faces[:, (k + 2) % 3]  # one of two free) comes first
        two = (count == 2) & ~touch[a0]
        frac[two] = 1.0 - (1.0 - cut(a1[two], a0[two])) * (1.0 - cut(a2[two], a0[two]))
        one = (count == 1) & touch[a0]
        frac[one] = cut(a0[one], a1[one]) * cut(a0[one], a2[one])
    if host["kind"][j] == KINDS["sphere"]:  # a face it reaches into counts whole (the mesh's resolution)
        frac = np.maximum(frac, face_contact_np(host, j, x[None], np.array([depth]))[2][0] > 0)
    return float(np.sum(frac * (fa @ u)))


def measure(setup: PressSetup) -> dict:
    """Force, pressure, contact area, penetration and stored energy of every world's press now."""
    sim = setup.sim
    host = sim.model.host.actuators["indenter"]
    W = sim.worlds
    x = sim.state.x.numpy().astype(np.float64)
    depth = np.diag(sim.control.values["indenter"].numpy()[:, :W])
    faces, u = sim.design.rest.faces, setup.directions
    out = {k: np.zeros(W) for k in ("force", "contact_area", "penetration", "surface_penetration")}
    for w in range(W):
        out["force"][w] = -float(np.sum(indenter_force_one(host, w, x[w], depth[w]) @ u[w]))
        out["penetration"][w] = max(-float(np.min(vertex_gaps(host, w, x[w], depth[w])[0])), 0.0)
        out["surface_penetration"][w] = max(float(surface_penetration_np(host, w, x[w:w + 1], depth[w:w + 1])[0]), 0.0)
        out["contact_area"][w] = contact_area(host, w, x[w], faces, depth[w], u[w])
    energy = sim.energy()
    stored = sum(np.atleast_1d(v) for k, v in energy.items() if k not in ("kinetic", "total"))
    return dict(out, pressure=np.atleast_1d(sim.pressure()), stored_energy=np.asarray(stored, dtype=np.float64),
                positions=x)


def set_depth(setup: PressSetup, depth: np.ndarray) -> None:
    """Every world's indenter to its depth (W,) m, with the vertices inside it moved onto its surface
    (the settle's start)."""
    sim = setup.sim
    W = sim.worlds
    depth = np.asarray(depth, dtype=np.float64)
    sim.set_actuator_controls("indenter", np.diag(depth))
    host = sim.model.host.actuators["indenter"]
    x = sim.positions.reshape(W, -1, 3).copy()
    for w in range(W):
        gap, normal = vertex_gaps(host, w, x[w], depth[w])
        x[w] -= np.minimum(gap, 0.0)[:, None] * normal
    sim.positions = x


def settle_at(setup: PressSetup, depth: np.ndarray, tolerance: float | None = None) -> None:
    """Settle every world with its indenter at depth (W,): first with the contact softened
    (``SOFT_CONTACT``: the membrane slides over the indenter to its place; to ``SOFT_TOLERANCE``), then at full stiffness (started
    afresh up to ``RESTARTS`` times; ``tolerance``: the full-stiffness settle's, N, None: the precision's);
    a world left with a residual force over ``RESIDUAL_LIMIT`` raises ``SimulationError``."""
    set_depth(setup, depth)
    sim = setup.sim
    k = sim.model.host.actuators["indenter"]["stiffness"].copy()
    set_indenter_stiffness(sim.model, SOFT_CONTACT * k)
    try:
        sim.settle_static(SOFT_TOLERANCE)
    finally:
        set_indenter_stiffness(sim.model, k)
    out = sim.settle_static(tolerance)
    for _ in range(RESTARTS):  # a settle stopped at its floor above the limit starts again from where it is
        if np.all(out.residual <= RESIDUAL_LIMIT):
            break
        out = sim.settle_static(tolerance)
    bad = np.flatnonzero(out.residual > RESIDUAL_LIMIT)
    if bad.size:
        w = int(bad[0])
        raise SimulationError(f"press: the membrane found no equilibrium at depth {depth[w] * 1e3:.4g} mm in world {w} "
                              f"(residual force {out.residual[w]:.3g} N); press less deep or with a larger radius",
                              quantity="equilibrium", world=w)


def advance(setup: PressSetup, start: np.ndarray, end: np.ndarray) -> None:
    """Press every world from depth ``start`` to ``end`` (W,) in increments of at most ``MAX_INCREMENT``,
    settling after each."""
    n = max(1, int(np.ceil(np.max(np.abs(end - start)) / MAX_INCREMENT - 1e-9)))
    for k in range(1, n + 1):
        settle_at(setup, start + (end - start) * (k / n))


def tangent_stiffness(setup: PressSetup, depth: np.ndarray) -> np.ndarray:
    """(W,) dF/d depth at the settled state of depth (W,) by central differences (``STIFFNESS_STEP``);
    the state is left as it was."""
    sim = setup.sim
    x0 = sim.positions.copy()
    f = []
    for sign in (1.0, -1.0):
        settle_at(setup, np.maximum(depth + sign * STIFFNESS_STEP, 0.0))
        f.append(measure(setup)["force"])
        sim.positions = x0
    sim.set_actuator_controls("indenter", np.diag(depth))
    lo = np.maximum(depth - STIFFNESS_STEP, 0.0)
    return (f[0] - f[1]) / (depth + STIFFNESS_STEP - lo)


def press_path(setup: PressSetup, depths: np.ndarray, jam: dict | None = None) -> list:
    """Every world through ``depths`` (n,) in turn (loading and unloading alike): the measures at each,
    with the tangent stiffness; after reaching depths[i], the cells ``jam[i]`` jam (in every world)."""
    W = setup.sim.worlds
    now = np.zeros(W)
    setup.sim.settle_static()
    rows = []
    for i, d in enumerate(depths):
        target = np.full(W, d)
        advance(setup, now, target)
        now = target
        row = measure(setup)
        row["stiffness"] = tangent_stiffness(setup, target)
        row["jammed"] = setup.sim.state.cell_jammed.copy()
        rows.append(row)
        for cell in (jam or {}).get(i, ()):
            setup.sim.jam(int(cell))
    return rows


def press(sim_or_result, direction, depths, indenter: str = "sphere", radius: float = DEFAULT_RADIUS,
          world: int = 0, jam: dict | None = None, stiffness: float = DEFAULT_CONTACT_STIFFNESS,
          plug_angle: float | None = None) -> Press:
    """Press a rigid frictionless ``indenter`` ("sphere": a fingertip of ``radius`` m; "plate": a palm)
    along -``direction`` onto the surface point that direction hits from the shape's centroid, to each
    of ``depths`` (m from first touch) in turn, quasi-statically, the device held at its plug. The
    state pressed is ``sim_or_result``'s world ``world`` (a Simulator; settled first, controls held) or a
    control result's final state replayed on its design. ``jam``: {i: cells} jams those cells once
    depths[i] is reached (they stay jammed). ``stiffness``: the contact penalty, N/m. ``plug_angle``: the
    held cap's half-angle around -z, degrees (None: ``PLUG_ANGLE``, 25 deg)."""
    src = source_simulator(sim_or_result, world)
    setup, depths = press_setup(src, world if isinstance(sim_or_result, Simulator) else 0, direction, indenter,
                                radius, depths, stiffness, plug_angle)
    if setup.sim.worlds != 1:
        raise DesignError("press takes one direction (a 3-vector); stiffness_map presses many")
    rows = press_path(setup, depths, jam)

    def col(key):
        return np.array([r[key][0] for r in rows])

    return Press(depth=depths, force=col("force"), stiffness=col("stiffness"), pressure=col("pressure"),
                 contact_area=col("contact_area"), penetration=col("penetration"),
                 surface_penetration=col("surface_penetration"),
                 stored_energy=col("stored_energy"), positions=col("positions"), point=setup.points[0],
                 direction=setup.directions[0], indenter=indenter, radius=float(radius), held=setup.held,
                 jammed=col("jammed"))


@dataclass
class FeelMap:
    """A stiffness map: per point (m,) the ``stiffness`` (N/m) and ``force`` (N) at ``depth`` m, the
    ``directions`` (m, 3) and surface ``points`` (m, 3) pressed, and the settled state's ``positions``
    (V, 3) m before pressing."""

    stiffness: np.ndarray
    force: np.ndarray
    directions: np.ndarray
    points: np.ndarray
    positions: np.ndarray
    depth: float
    radius: float


def feel_map(sim_or_result, directions, depth: float = 0.002, radius: float = DEFAULT_RADIUS,
             indenter: str = "sphere", world: int = 0, plug_angle: float | None = None) -> FeelMap:
    """``stiffness_map`` with what was pressed where (``FeelMap``)."""
    src = source_simulator(sim_or_result, world)
    setup, depths = press_setup(src, world if isinstance(sim_or_result, Simulator) else 0, directions, indenter,
                                radius, [depth], plug_angle=plug_angle)
    start = setup.sim.positions.reshape(setup.sim.worlds, -1, 3)[0].copy()
    row = press_path(setup, depths)[0]
    return FeelMap(stiffness=row["stiffness"], force=row["force"], directions=setup.directions, points=setup.points,
                   positions=start, depth=float(depths[0]), radius=float(radius))


def stiffness_map(sim_or_result, directions, depth: float = 0.002, radius: float = DEFAULT_RADIUS,
                  indenter: str = "sphere", world: int = 0, plug_angle: float | None = None) -> np.ndarray:
    """(m,) N/m: the tangent stiffness dF/d depth of a press to ``depth`` m along each of ``directions``
    (m, 3), one press per world of one batch (see ``press``)."""
    return feel_map(sim_or_result, directions, depth, radius, indenter, world, plug_angle).stiffness


def pressable_directions(sim_or_result, count: int, world: int = 0, plug_angle: float | None = None,
                         radius: float = DEFAULT_RADIUS) -> np.ndarray:
    """(m, 3) of ``count`` directions spread evenly over the sphere (a Fibonacci lattice), those whose
    ray from the centroid misses the shape or meets it within 2 ``radius`` of the held plug left out."""
    src = source_simulator(sim_or_result, world)
    x = np.asarray(src.state.x.numpy()[world if isinstance(sim_or_result, Simulator) else 0], dtype=np.float64)
    faces = src.design.rest.faces
    held = plug_vertices(x, faces, None if plug_angle is None else np.radians(check_plug_angle(plug_angle)))
    k = np.arange(count) + 0.5
    z = 1 - 2 * k / count
    phi = np.pi * (1 + 5 ** 0.5) * k
    dirs = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
    keep = []
    for d in dirs:
        hit = surface_point(x, faces, x.mean(axis=0), d)
        keep.append(hit is not None and not touches_plug(x, held, hit[0], 2.0 * radius))
    return dirs[np.asarray(keep, dtype=bool)]


# ---------------------------------------------------------------------- how the controls move the stiffness
@dataclass
class StiffnessGradient:
    """How the controls move the stiffness felt at one press. At ``depth`` (m from first touch): ``stiffness``
    (N/m, dF/d depth by central differences of +-``STIFFNESS_STEP``, as ``press``), ``force`` (N) and the
    chamber's gauge ``pressure`` (Pa); the stiffness's derivatives at that equilibrium, the finger held where
    it is (its depth counted from the first touch of the state before the change), by implicit
    differentiation: ``air`` (N/m per mol of air), ``pressures`` (n_ipam,) (N/m per Pa of each IPAM's gauge
    pressure; 0 where an IPAM is disabled), ``cells`` (n_cells,) (N/m per unit of ln s, s a factor on the
    stretch and bending stiffness of the cell's edges as the state holds them: for a jammed cell, its
    jam's stiffening factor); ``converged``: every adjoint solve reached its tolerance."""

    depth: float
    stiffness: float
    force: float
    pressure: float
    air: float
    pressures: np.ndarray
    cells: np.ndarray
    converged: bool


def contact_force_gradient(host: dict, x: np.ndarray, depth: float, i: int = 0, step: float = 1e-7) -> np.ndarray:
    """(V, 3) dF/dx, F (N) the push of indenter ``i`` of ``host`` (the indenter family's host arrays) at
    ``depth`` m on the vertices x (V, 3) along its press (-axis), faces included (``indenter_force_one``):
    central differences of ``step`` m on the coordinates of the vertices of the faces within 1 mm of the
    indenter (the law is smooth in x away from its kinks: exact to the differences' rounding there)."""
    axis = np.asarray(host["axis"][i], dtype=np.float64)
    c = np.asarray(host["origin"][i], dtype=np.float64) - depth * axis
    x = np.asarray(x, dtype=np.float64)
    if int(host["kind"][i]) == KINDS["plate"]:
        near = (x - c) @ axis > -1e-3
    else:  # the fingertip acts on faces: every vertex of a face that reaches within 1 mm of it
        tri = x[host["faces"]]
        reach = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=-1))
        near = np.linalg.norm(x - c, axis=1) < float(host["radius"][i]) + reach + 1e-3

    def push(y):
        return -float(np.sum(indenter_force_one(host, i, y, depth) @ axis))

    g = np.zeros_like(x)
    for v in np.flatnonzero(near):
        for k in range(3):
            y = x.copy()
            y[v, k] += step
            up = push(y)
            y[v, k] -= 2 * step
            g[v, k] = (up - push(y)) / (2 * step)
    return g


def force_gradient(setup: PressSetup, eg: EquilibriumGradient, depth: float, tolerance: float, guess=None):
    """At the press's settled state at ``depth``: (F N, gauge pressure Pa, dF/d air, dF/d IPAM pressures,
    dF/d edge fields (4, E), the solve's ControlGradient) by the equilibrium's adjoint."""
    sim = setup.sim
    x = sim.positions.reshape(-1, 3).astype(np.float64)
    host = sim.model.host
    enabled = sim.control.enabled["ipam"].numpy()[0, :host.n_ipams].astype(bool) if host.n_ipams else None
    eg.load(x, sim.state.edge.numpy()[:, 0].astype(np.float64), float(sim.air_moles),
            np.atleast_2d(sim.ipam_pressures)[0] if host.n_ipams else np.zeros(0), enabled,
            controls={"indenter": np.array([depth])})
    eg.add_to_preconditioner(contact_stiffness_diagonal(sim, x, depth))
    cg = eg.control_gradient(contact_force_gradient(host.actuators["indenter"], x, depth), tolerance=tolerance,
                             guess=guess)
    return float(measure(setup)["force"][0]), eg.gauge_pressure(), cg


def contact_stiffness_diagonal(sim: Simulator, x: np.ndarray, depth: float, i: int = 0) -> np.ndarray:
    """(V,) the hold's and indenter ``i``'s stiffness on the vertices they act on (N/m): their part of the
    adjoint solve's preconditioner."""
    host = sim.model.host
    d = np.zeros(len(x))
    hold = host.actuators["hold"]
    np.add.at(d, np.asarray(hold["vertex"]), np.asarray(hold["stiffness"], dtype=np.float64))
    ind = host.actuators["indenter"]
    axis = np.asarray(ind["axis"][i], dtype=np.float64)
    c = np.asarray(ind["origin"][i], dtype=np.float64) - depth * axis
    if int(ind["kind"][i]) == KINDS["plate"]:
        pen = (x - c) @ axis
    else:
        pen = float(ind["radius"][i]) - np.linalg.norm(x - c, axis=1)
    d[pen > -2e-4] += float(ind["stiffness"][i])
    return d


def stiffness_gradient(sim_or_result, direction, depth: float = 0.002, radius: float = DEFAULT_RADIUS,
                       indenter: str = "sphere", world: int = 0, plug_angle: float | None = None,
                       tolerance: float = 1e-11) -> StiffnessGradient:
    """The stiffness a fingertip (or palm) pressed ``depth`` m along -``direction`` feels (as ``press``) and its
    derivatives with respect to the air, the IPAM pressures and each cell's stiffness (a jam's), at that
    equilibrium by implicit differentiation (``gradients.equilibrium``: K mu = dF/dx, dF/du = mu^T dR/du,
    R the net force), at the two settled depths of the stiffness's central difference (settled to
    ``EQUILIBRIUM_TOLERANCE``). ``tolerance``: the adjoint solves' relative residual (the stiffness's
    derivative is a difference of two nearly equal force derivatives, so it needs a tight one)."""
    src = source_simulator(sim_or_result, world)
    setup, depths = press_setup(src, world if isinstance(sim_or_result, Simulator) else 0, direction, indenter,
                                radius, [depth], plug_angle=plug_angle)
    if setup.sim.worlds != 1:
        raise DesignError("stiffness_gradient takes one direction (a 3-vector)")
    sim = setup.sim
    press_path(setup, depths)  # the state at depth
    eg = EquilibriumGradient(sim.model.host, sim.design.material, sim.device)
    x0 = sim.positions.copy()
    rows, guess = [], None
    lo = max(float(depths[0]) - STIFFNESS_STEP, 0.0)
    for d in (float(depths[0]) + STIFFNESS_STEP, lo):
        settle_at(setup, np.array([d]), EQUILIBRIUM_TOLERANCE)
        f, p, cg = force_gradient(setup, eg, d, tolerance, guess)
        guess = cg.adjoint
        rows.append((f, p, cg, eg.edge.grad.numpy()[:, 0].astype(np.float64)))
        sim.positions = x0
    sim.set_actuator_controls("indenter", np.array([[depths[0]]]))
    h = float(depths[0]) + STIFFNESS_STEP - lo
    (f1, p1, c1, e1), (f0, p0, c0, e0) = rows
    edge = sim.state.edge.numpy()[:, 0].astype(np.float64)
    de = (e1 - e0) / h * edge  # dk / d ln(edge field)
    cells = np.array([float(de[2, c].sum() + de[3, c].sum()) for c in sim.model.host.cell_edges])
    return StiffnessGradient(depth=float(depths[0]), stiffness=(f1 - f0) / h, force=float(measure(setup)["force"][0]),
                             pressure=0.5 * (p0 + p1), air=(c1.air - c0.air) / h,
                             pressures=(c1.pressures - c0.pressures) / h, cells=cells,
                             converged=bool(c0.converged and c1.converged))
