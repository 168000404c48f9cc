"""Contact with rigid frictionless indenters (a fingertip sphere, a flat plate) and the hold of the
device at its plug, as force families: launch wrappers, float64 host laws, stable-step rows.

``IndenterFamily`` ("indenter") is an actuator family whose control is each indenter's depth (m)
along -axis from its reference point, so the static settle presses to a given depth with the same
machinery as any other control; ``HoldFamily`` ("hold") is a passive family of zero-length springs
tying vertices to fixed points (the plug). docs/feel.md describes the model and its error: the
penalty's penetration is a vertex's contact force over its stiffness, so a vertex carrying at most
F_max N penetrates at most F_max / k (``DEFAULT_CONTACT_STIFFNESS``: 2e5 N/m, 0.05 mm at 10 N on one vertex).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warp_shape.kernels import contact as kc

from ..errors import DesignError
from ..force_family import ACTUATOR_FAMILIES, FORCE_FAMILIES, ActuatorFamily, ForceFamily

__all__ = ["Indenter", "Hold", "IndenterFamily", "HoldFamily", "INDENTER", "HOLD", "add_indenter", "add_hold",
           "KINDS", "DEFAULT_CONTACT_STIFFNESS", "DEFAULT_RADIUS", "indenter_centres", "penetration_np",
           "closest_weights_np", "face_contact_np", "surface_penetration_np", "indenter_force_one",
           "indenter_forces_np", "indenter_energy_np", "set_indenter_stiffness"]

#: indenter kinds, by name -> kernel code
KINDS = {"sphere": 0, "plate": 1}
#: penalty stiffness of a contact, N/m: a vertex carrying 10 N penetrates 0.05 mm
DEFAULT_CONTACT_STIFFNESS = 2.0e5
#: the fingertip's radius, m
DEFAULT_RADIUS = 0.008
#: a vertex this close to an indenter (m) gets its stiffness on the settle's preconditioner
PRECONDITION_MARGIN = 2.0e-4


@dataclass(frozen=True)
class Indenter:
    """A rigid frictionless indenter: ``kind`` "sphere" or "plate", unit ``axis`` pointing out of the
    device (it presses along -axis), ``origin`` (m) its sphere's centre / a point of its plane at depth 0,
    ``radius`` (m, the sphere's), penalty ``stiffness`` (N/m)."""

    kind: str
    axis: tuple
    origin: tuple
    radius: float
    stiffness: float
    world: int = -1  # the one world it presses in (its index = the world's: a stiffness map), or -1: every world


@dataclass(frozen=True)
class Hold:
    """Vertex ``vertex`` held at ``point`` (m) by a zero-length spring of ``stiffness`` N/m."""

    vertex: int
    point: tuple
    stiffness: float


def add_indenter(design, kind: str, axis, origin, radius: float = DEFAULT_RADIUS,
                 stiffness: float = DEFAULT_CONTACT_STIFFNESS, world: int = -1) -> int:
    """Add an indenter to ``design`` (see ``Indenter``); returns its index. ``world`` >= 0: it presses in that
    world only (its mask must say so too); when indenter j presses in world j for every j, a force
    evaluation visits one indenter per world instead of all of them."""
    if kind not in KINDS:
        raise DesignError(f"indenter must be one of {sorted(KINDS)}, got {kind!r}")
    u = np.asarray(axis, dtype=np.float64).reshape(3)
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(u))
    if not (np.all(np.isfinite(u)) and n > 0 and np.all(np.isfinite(o))):
        raise DesignError(f"an indenter needs a finite non-zero axis and a finite origin, got {u}, {o}")
    if not (np.isfinite(radius) and radius > 0 and np.isfinite(stiffness) and stiffness > 0):
        raise DesignError(f"an indenter needs radius > 0 m and stiffness > 0 N/m, got {radius}, {stiffness}")
    return design.add_element("indenter", Indenter(kind, tuple(u / n), tuple(o), float(radius), float(stiffness),
                                                   int(world)))


def add_hold(design, vertices, points, stiffness: float) -> None:
    """Hold ``vertices`` (n,) of ``design`` at ``points`` (n, 3) m by zero-length springs of ``stiffness`` N/m."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vs = [design.check_vertex(v, "held vertex") for v in np.asarray(vertices).reshape(-1)]
    if len(vs) != len(pts) or not np.all(np.isfinite(pts)) or not stiffness > 0:
        raise DesignError(f"a hold needs one finite point per vertex and stiffness > 0 N/m, got {len(vs)} vertices, "
                          f"{len(pts)} points, {stiffness} N/m")
    for v, p in zip(vs, pts):
        design.add_element("hold", Hold(v, tuple(p), float(stiffness)))


def set_indenter_stiffness(model, stiffness) -> None:
    """Every indenter's penalty stiffness (N/m; a scalar or (n,)) in ``model``, on the device and in its
    host arrays alike (a press softens its contact for a first settle, then restores it)."""
    host = model.host.actuators["indenter"]
    host["stiffness"][:] = np.broadcast_to(np.asarray(stiffness, dtype=np.float64), host["stiffness"].shape)
    model.actuators["indenter"]["stiffness"].assign(host["stiffness"].astype(model.np_dtype))


# ---------------------------------------------------------------------- host law (float64)
def closest_weights_np(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(..., 3) barycentric weights of the point of each triangle abc (..., 3) closest to p (..., 3)."""
    dot = lambda u, v: np.einsum("...i,...i->...", u, v)  # noqa: E731
    ab, ac = b - a, c - a
    d1, d2 = dot(ab, p - a), dot(ac, p - a)
    d3, d4 = dot(ab, p - b), dot(ac, p - b)
    d5, d6 = dot(ab, p - c), dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def safe(n, d):
        return n / np.where(d == 0, 1.0, d)

    s = va + vb + vc
    out = np.stack([safe(va, s), safe(vb, s), safe(vc, s)], axis=-1)  # inside the face
    t_bc = safe(d4 - d3, (d4 - d3) + (d5 - d6))
    t_ac, t_ab = safe(d2, d2 - d6), safe(d1, d1 - d3)
    o, z = np.ones_like(d1), np.zeros_like(d1)
    regions = [  # the first that holds wins (as in the kernel)
        (d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (d6 >= 0) & (d5 <= d6),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)]
    values = [(o, z, z), (z, o, z), (z, z, o), (1 - t_ab, t_ab, z), (1 - t_ac, z, t_ac), (z, 1 - t_bc, t_bc)]
    for cond, val in zip(regions[::-1], values[::-1]):
        out = np.where(cond[..., None], np.stack(val, axis=-1), out)
    return out


def face_contact_np(host: dict, j: int, x: np.ndarray, depth: np.ndarray):
    """(weights (W, F, 3), points (W, F, 3), penetration (W, F)): every face's point of x (W, V, 3) closest
    to sphere j's centre at depths (W,) m, and how deep it lies inside (m; <= 0 outside); for a plate, its
    faces' deepest vertex."""
    faces = host["faces"]
    c = host["origin"][j][None, None, :] - np.asarray(depth, dtype=np.float64).reshape(-1, 1, 1) * host["axis"][j]
    a, b, cc = (x[:, faces[:, k]] for k in range(3))  # (W, F, 3)
    wts = closest_weights_np(c, a, b, cc)
    q = wts[..., 0:1] * a + wts[..., 1:2] * b + wts[..., 2:3] * cc
    if host["kind"][j] == KINDS["sphere"]:
        return wts, q, host["radius"][j] - np.linalg.norm(q - c, axis=-1)
    return wts, q, np.einsum("wvi,i->wv", x - c, host["axis"][j])[:, faces].max(axis=-1)


def surface_penetration_np(host: dict, j: int, x: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(W,) the deepest point of the surface of x (W, V, 3) (any point of any face) inside indenter j at
    depths (W,), m."""
    return face_contact_np(host, j, x, depth)[2].max(axis=-1)


def indenter_centres(host: dict, depth: np.ndarray) -> np.ndarray:
    """(W, n, 3) each indenter's centre / plane point at depths (W, n) m."""
    return host["origin"][None] - np.asarray(depth, dtype=np.float64)[..., None] * host["axis"][None]


def penetration_np(host: dict, x: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(W, n, V) penetration of every vertex of x (W, V, 3) into every indenter (m; <= 0 outside)."""
    c = indenter_centres(host, depth)
    d = x[:, None, :, :] - c[:, :, None, :]  # (W, n, V, 3)
    plate = np.einsum("wnvi,ni->wnv", d, host["axis"])
    sphere = host["radius"][None, :, None] - np.linalg.norm(d, axis=-1)
    return np.where((host["kind"] == KINDS["sphere"])[None, :, None], sphere, plate)


def indenter_forces_np(host: dict, x: np.ndarray, depth: np.ndarray, enabled: np.ndarray) -> np.ndarray:
    """(W, n, V, 3) each enabled indenter's force on every vertex, N (a sphere's on the faces, shared by
    their vertices; a plate's on the vertices)."""
    W, V = x.shape[:2]
    out = np.zeros((W, len(host["kind"]), V, 3))
    for j, w in zip(*np.nonzero(np.asarray(enabled, bool).T)):
        out[w, j] = indenter_force_one(host, j, x[w], float(depth[w, j]))
    return out


def indenter_force_one(host: dict, j: int, x: np.ndarray, depth: float) -> np.ndarray:
    """(V, 3) indenter j's force at depth m on the vertices x (V, 3), N."""
    k = host["stiffness"][j]
    if host["kind"][j] == KINDS["plate"]:
        pen = np.maximum(penetration_np(host, x[None], np.full((1, len(host["kind"])), depth))[0, j], 0.0)
        return -k * pen[:, None] * host["axis"][j]
    wts, q, pen = (a[0] for a in face_contact_np(host, j, x[None], np.array([depth])))
    d = q - (host["origin"][j] - depth * host["axis"][j])
    push = k * np.maximum(pen, 0.0)[:, None] * d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    out = np.zeros_like(x)
    for m in range(3):
        np.add.at(out, host["faces"][:, m], push * wts[:, m:m + 1])
    return out


def indenter_energy_np(host: dict, x: np.ndarray, depth: np.ndarray, enabled: np.ndarray) -> np.ndarray:
    """(W,) penalty energy sum k pen^2 / 2 over enabled indenters and their penetrating faces (a sphere)
    or vertices (a plate), J."""
    out = np.zeros(x.shape[0])
    for j, w in zip(*np.nonzero(np.asarray(enabled, bool).T)):
        if host["kind"][j] == KINDS["plate"]:
            pen = penetration_np(host, x[w:w + 1], np.asarray(depth, dtype=np.float64)[w:w + 1])[0, j]
        else:
            pen = face_contact_np(host, j, x[w:w + 1], np.array([depth[w, j]]))[2][0]
        out[w] += 0.5 * host["stiffness"][j] * float(np.sum(np.maximum(pen, 0.0) ** 2))
    return out


class IndenterFamily(ActuatorFamily):
    """Rigid frictionless indenters whose control is their depth (m)."""

    name = "indenter"
    summary = "a rigid frictionless indenter (sphere or plate) pressed to a depth, penalty contact"
    label, plural = "indenter", "indenters"
    owner = "physics.contact.add_indenter"
    control_unit, control_name, limits_name = "m", "depth", "its depth range"
    scene_prim = "Indenters"
    rigid_invariant = False  # a rigid indenter fixed in space
    differentiable = True
    parameters = {"origin": "m", "radius": "m", "stiffness": "N/m"}

    def host_arrays(self, design) -> dict:
        els = design.elements(self.name)
        return dict(kind=np.array([KINDS[e.kind] for e in els], dtype=np.int64),
                    axis=np.array([e.axis for e in els], dtype=np.float64).reshape(-1, 3),
                    origin=np.array([e.origin for e in els], dtype=np.float64).reshape(-1, 3),
                    radius=np.array([e.radius for e in els], dtype=np.float64),
                    stiffness=np.array([e.stiffness for e in els], dtype=np.float64),
                    world=np.array([e.world for e in els], dtype=np.int64),
                    faces=design.rest.faces.astype(np.int64))

    def device_arrays(self, host, arr) -> dict:
        vec = wp.types.vector(3, arr(np.zeros(1)).dtype)
        return dict(kind=arr(host["kind"].astype(np.int32), wp.int32), axis=arr(host["axis"], vec),
                    origin=arr(host["origin"], vec), radius=arr(host["radius"]), stiffness=arr(host["stiffness"]),
                    faces=arr(host["faces"].astype(np.int32), wp.vec3i))

    def eval_forces(self, model, state, control, x, v, f, launch):
        n = model.host.count(self.name)
        if not n:
            return
        dev = model.actuators[self.name]
        world = model.host.actuators[self.name]["world"]
        own = int(n == x.shape[0] and np.array_equal(world, np.arange(n)))
        args = [dev["kind"], dev["axis"], dev["origin"], dev["radius"], dev["stiffness"], own,
                control.values[self.name], control.enabled[self.name], x, f]
        launch(kc.indenter_force_kernel, (x.shape[0], x.shape[1]), args)  # the plates, on the vertices
        launch(kc.indenter_face_force_kernel, (x.shape[0], dev["faces"].shape[0]), [dev["faces"], *args])  # spheres

    def diagonal_stiffness(self, model, state, diag, launch, control=None):
        if control is None:  # where the indenters are is unknown: nothing added
            return
        dev = model.actuators[self.name]
        args = [dev["kind"], dev["axis"], dev["origin"], dev["radius"], dev["stiffness"],
                model.scalar(PRECONDITION_MARGIN), control.values[self.name], control.enabled[self.name], state.x, diag]
        launch(kc.indenter_diagonal_kernel, (state.x.shape[0], state.x.shape[1]), args)
        launch(kc.indenter_face_diagonal_kernel, (state.x.shape[0], dev["faces"].shape[0]), [dev["faces"], *args])

    def energy(self, host, x, controls, enabled):
        return indenter_energy_np(host, x, controls, enabled)

    def stiffness_rows(self, stiff, damp, host, inv_m, inv_sqrt):
        # a vertex may touch every indenter, a sphere through each of its faces (k b^2 per face, b <= 1): its
        # row gains their stiffness times its faces (the step with an indenter is as short as the penalty asks)
        faces_at = np.maximum(np.bincount(host["faces"].reshape(-1), minlength=inv_m.shape[-1]), 1)
        stiff += float(np.sum(host["stiffness"])) * (faces_at * inv_m)[None, :]

    def storable_values(self, host):
        return {"stiffness": host["stiffness"], "radius": host["radius"]}

    def curve_ends(self, design, positions):
        ends = []
        for e in design.elements(self.name):
            o, u = np.asarray(e.origin), np.asarray(e.axis)
            ends.append([o, o + u * max(e.radius, 0.01)])
        ends = np.asarray(ends, dtype=np.float64).reshape(-1, 2, 3)
        lead = np.asarray(positions).shape[:-2]
        return np.broadcast_to(ends, lead + ends.shape).copy()

    def add_from_scene(self, design, values, i):
        raise DesignError("indenters are not read from scenes: a press adds them (ws.press)")


class HoldFamily(ForceFamily):
    """Vertices tied to fixed points by stiff zero-length springs (the plug a press holds)."""

    name = "hold"
    summary = "vertices tied to fixed points by zero-length springs (the device held at its plug)"
    label, plural = "held vertex", "held vertices"
    owner = "physics.contact.add_hold"
    rigid_invariant = False  # it ties the membrane to points in space
    differentiable = True
    parameters = {"point": "m", "stiffness": "N/m"}

    def host_arrays(self, design) -> dict:
        els = design.elements(self.name)
        return dict(vertex=np.array([e.vertex for e in els], dtype=np.int64),
                    point=np.array([e.point for e in els], dtype=np.float64).reshape(-1, 3),
                    stiffness=np.array([e.stiffness for e in els], dtype=np.float64))

    def device_arrays(self, host, arr) -> dict:
        vec = wp.types.vector(3, arr(np.zeros(1)).dtype)
        return dict(vertex=arr(host["vertex"].astype(np.int32), wp.int32), point=arr(host["point"], vec),
                    stiffness=arr(host["stiffness"]))

    def eval_forces(self, model, state, control, x, v, f, launch):
        n = model.host.count(self.name)
        if not n:
            return
        dev = model.actuators[self.name]
        launch(kc.hold_force_kernel, (x.shape[0], n), [dev["vertex"], dev["point"], dev["stiffness"], x, f])

    def diagonal_stiffness(self, model, state, diag, launch, control=None):
        dev = model.actuators[self.name]
        launch(kc.hold_diagonal_kernel, (state.x.shape[0], len(dev["vertex"])), [dev["vertex"], dev["stiffness"], diag])

    def energy(self, host, x, controls, enabled):
        d = x[:, host["vertex"]] - host["point"][None]
        return 0.5 * np.einsum("n,wni,wni->w", host["stiffness"], d, d)

    def stiffness_rows(self, stiff, damp, host, inv_m, inv_sqrt):
        np.add.at(stiff, (slice(None), host["vertex"]), host["stiffness"] * inv_m[host["vertex"]])

    def storable_values(self, host):
        return {"stiffness": host["stiffness"]}


INDENTER = ACTUATOR_FAMILIES.register(IndenterFamily())
HOLD = FORCE_FAMILIES.register(HoldFamily())
