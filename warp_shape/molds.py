"""Fabrication molds (paper section V-D): a core and a two-part shell a 3-D printer can make.

Geometry is built in metres (the design's units) and written in the units a slicer expects
(millimetres by default). Every solid operation is a manifold boolean (trimesh with the manifold3d
engine), so each part is a closed, watertight, manifold solid.

- **core**: the rest shape (the inner membrane's surface) with a cylindrical boss raised on every
  IPAM attachment face, where the actuator end caps are glued, standing on a flat seat (a stem
  under the centroid, where the air tubes leave the device), so it prints without supports. Brush
  silicone over it for the inner membrane.
- **shell**: a block whose cavity is the membrane's outer surface, i.e. the rest shape moved radially
  outward by the jamming-layer thickness (:func:`outer_mold`). It is split on a horizontal plane (the
  cavity's widest section, so both halves release) into a bottom half carrying three registration
  keys (pins, asymmetric so the halves fit one way only) and a top half carrying the matching key
  holes, a pour hole above the cavity's highest point and a vent hole.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from .display import Design
from .errors import DesignError
from .mesh import TriMesh

__all__ = ["outer_mold", "MoldSet", "mold_set", "mold_core", "core_seat", "seat_place", "UNIT_SCALES",
           "check_mold_lengths", "equivalent_radius"]

#: output unit -> factor from metres
UNIT_SCALES = {"mm": 1000.0, "cm": 100.0, "m": 1.0, "in": 1000.0 / 25.4}
#: The thickest jamming layer and the tallest IPAM marker a mold takes, as fractions of the device's
#: radius: anything beyond is a length in the wrong unit, not a design.
MOLD_LENGTH_LIMITS = {"layer_thickness": ("jamming layer", 0.5, False), "marker_height": ("IPAM marker", 0.25, True)}


def equivalent_radius(mesh: TriMesh) -> float:
    """Radius (m) of the sphere of ``mesh``'s volume: the size of a device or a target."""
    return float((3.0 * mesh.volume() / (4.0 * np.pi)) ** (1.0 / 3.0))


def check_mold_lengths(radius: float, *, spell=lambda name: name, **lengths) -> None:
    """``layer_thickness`` and ``marker_height`` (m) checked against a device ``radius`` (m) before
    any work: finite, > 0 (a marker: >= 0) and at most its ``MOLD_LENGTH_LIMITS`` share of the radius.
    ``spell`` names a length in the message (the command line passes its flags). ``DesignError`` names
    the range and, for a value that fits it in millimetres, the value in metres."""
    for name, value in lengths.items():
        what, share, zero_ok = MOLD_LENGTH_LIMITS[name]
        hi = share * radius
        real = isinstance(value, numbers.Real) and not isinstance(value, bool)
        finite = real and math.isfinite(value)
        if finite and (value >= 0 if zero_ok else value > 0) and value <= hi:
            continue
        mm = f"; if {value:g} is millimetres: {spell(name)} {value * 1e-3:g}" if finite and 0 < value * 1e-3 <= hi else ""
        raise DesignError(f"{spell(name)} {f'{value:g} m' if finite else repr(value)} is no {what} for a device {radius * 1e3:.0f} mm in radius: give "
                          f"metres, {'0 <=' if zero_ok else '0 <'} {spell(name)} <= {hi:.3g}{mm}")


def outer_mold(design: Design, layer_thickness: float = 5e-3) -> TriMesh:
    """Rest shape moved radially outward (from its volume centroid) by ``layer_thickness`` m: the
    membrane's outer surface and the shell's cavity (metres)."""
    if not 0 < layer_thickness < math.inf:
        raise DesignError(f"layer_thickness must be a length > 0 m, got {layer_thickness}")
    rest = design.rest
    c = rest.centroid()
    d = rest.vertices - c
    r = np.linalg.norm(d, axis=1, keepdims=True)
    return TriMesh(c + d * (1.0 + layer_thickness / r), rest.faces)


def ipam_end_faces(design: Design) -> list[int]:
    """Sorted face indices where an IPAM end cap is attached."""
    return sorted({f for ip in design.ipams for f in (ip.face_a, ip.face_b)})


@dataclass
class MoldSet:
    """The printable molds in ``units`` (trimesh solids) and a description of them (``info``, the
    JSON sidecar: units, parameters, split plane, key, pour and vent positions, IPAM markers, and per
    part its extents, volume and watertightness)."""

    units: str
    core: object  # trimesh.Trimesh
    shell_bottom: object
    shell_top: object
    cavity: object  # the membrane's outer surface, same units (a reference, not a file)
    info: dict = field(default_factory=dict)

    def parts(self) -> dict:
        """File stem -> solid: ``mold_core``, ``mold_shell_bottom``, ``mold_shell_top``."""
        return {"mold_core": self.core, "mold_shell_bottom": self.shell_bottom, "mold_shell_top": self.shell_top}


def _engine():
    try:
        import manifold3d  # noqa: F401
    except ImportError:
        raise DesignError("mold booleans need the manifold3d package: pip install manifold3d "
                          "(a dependency of warp-shape)") from None
    return "manifold"


def _bool(op: str, meshes):
    import trimesh

    fn = {"union": trimesh.boolean.union, "difference": trimesh.boolean.difference,
          "intersection": trimesh.boolean.intersection}[op]
    out = fn(list(meshes), engine=_engine())
    if not out.is_watertight or out.volume <= 0:
        raise DesignError(f"mold {op} gave an open or empty solid; check that the rest shape is a closed, "
                          f"non-self-intersecting mesh and the mold parameters fit its size")
    return out


def _cylinder(p0, p1, radius: float, sections: int = 32):
    import trimesh

    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], dtype=float), sections=sections)


def mold_core(design: Design, *, marker_height: float = 2e-3, marker_radius: float = 3e-3,
              seat_radius: float = 25e-3, seat_height: float = 5e-3):
    """The core (metres): the rest shape unioned with a boss of radius ``marker_radius`` standing
    ``marker_height`` proud of every IPAM end face (along its normal, from the face centroid), and a
    flat seat below (``core_seat``). Returns (solid, markers, seat): markers lists per IPAM end its
    face, the face centroid and the boss tip position; seat describes the stem."""
    if not (0 <= marker_height < math.inf and 0 < marker_radius < math.inf):
        raise DesignError(f"marker_height must be >= 0 m and marker_radius > 0 m, got {marker_height}, {marker_radius}")
    rest = design.rest
    centroids, normals = rest.face_centroids(), rest.face_normals()
    solid = rest.to_trimesh()
    markers = []
    for i, ip in enumerate(design.ipams):
        for end, f in (("a", ip.face_a), ("b", ip.face_b)):
            markers.append({"ipam": i, "end": end, "face": int(f), "face_centroid": centroids[f].tolist(),
                            "position": (centroids[f] + marker_height * normals[f]).tolist()})
    if marker_height > 0 and design.ipams:
        bosses = [_cylinder(centroids[f] - max(marker_height, marker_radius) * normals[f],
                            centroids[f] + marker_height * normals[f], marker_radius)
                  for f in ipam_end_faces(design)]
        solid = _bool("union", [solid, *bosses])
    centre, radius = seat_place(rest.to_trimesh(), centroids[ipam_end_faces(design)] if design.ipams else
                                np.zeros((0, 3)), seat_radius=seat_radius, clearance=marker_radius + 1e-3)
    stem, seat = core_seat(solid, centre, seat_radius=radius, seat_height=seat_height)
    seat["covers_ipam_ends"] = [dict(ipam=m["ipam"], end=m["end"]) for m in markers
                                if np.hypot(*(np.array(m["face_centroid"][:2]) - seat["center"][:2])) < seat["radius"]
                                and m["face_centroid"][2] < seat["top_z"]]
    return _bool("union", [solid, stem]), markers, seat


def seat_place(body, ends: np.ndarray, *, seat_radius: float = 25e-3, clearance: float = 4e-3,
               min_radius: float = 8e-3, spacing: float = 2e-3) -> tuple[np.ndarray, float]:
    """Where the core's seat goes (metres): (xy centre, radius). Under the body's centroid where no
    IPAM end (``ends``, (n, 3)) lies within the seat plus ``clearance``; else the lowest spot of the
    underside, on a grid of ``spacing``, whose disk of at least ``min_radius`` keeps that clearance
    (widest first among equally low ones); no such spot: under the centroid, covering the ends."""
    cap = min(float(seat_radius), 0.3 * float(np.min(body.extents[:2])))
    centre = np.asarray(body.centroid, dtype=np.float64)[:2]
    low = ends[ends[:, 2] < body.bounds[0, 2] + 0.5 * body.extents[2]] if len(ends) else ends

    def room(xy):  # (P,) the widest seat at each xy keeping the clearance from the low IPAM ends
        if not len(low):
            return np.full(len(xy), cap)
        d = np.linalg.norm(xy[:, None, :] - low[None, :, :2], axis=2).min(axis=1)
        return np.minimum(cap, d - clearance)

    if room(centre[None])[0] >= cap:
        return centre, cap
    lo, hi = body.bounds[0, :2] + cap, body.bounds[1, :2] - cap
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1e-9, spacing), np.arange(lo[1], hi[1] + 1e-9, spacing))
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    r = room(xy)
    z = np.nanmin(vertical_crossings(body, xy), axis=1) if len(xy) else np.zeros(0)
    ok = (r >= min_radius) & np.isfinite(z)
    if not ok.any():
        return centre, cap
    k = np.flatnonzero(ok)[np.lexsort((-r[ok], np.round(z[ok], 3)))[0]]
    return xy[k], float(r[k])


def core_seat(solid, centre, *, seat_radius: float = 25e-3, seat_height: float = 5e-3):
    """A flat seat for the core (metres), so that it stands on the print bed without supports: a
    vertical stem of ``seat_radius`` (at most 30 % of the core's narrower horizontal extent) with its
    axis at ``centre`` (x, y; ``seat_place``), from ``seat_height`` below the core's lowest point up
    into the body.
    It is where the paper's air tubes leave the device (a plug a few centimetres across): the inner
    membrane brushed over the core keeps an opening there. Returns (stem solid, seat description)."""
    if not (seat_radius > 0 and seat_height > 0):
        raise DesignError(f"seat_radius and seat_height must be > 0 m, got {seat_radius}, {seat_height}")
    radius = min(float(seat_radius), 0.3 * float(np.min(solid.extents[:2])))
    xy = np.asarray(centre, dtype=np.float64)[:2]
    ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    rings = [xy + f * radius * np.stack([np.cos(ang), np.sin(ang)], axis=1) for f in (0.5, 1.0)]
    pts = np.concatenate([xy[None], *rings])
    z = vertical_crossings(solid, pts)
    if np.any(np.all(np.isnan(z), axis=1)):
        raise DesignError("the core's seat does not lie under the core; use a smaller seat_radius")
    lower = np.nanmin(z, axis=1)  # the core's underside over the seat's disk
    bottom = min(float(solid.bounds[0, 2]), float(lower.min())) - float(seat_height)
    top = float(lower.max()) + 1e-3
    stem = _cylinder([xy[0], xy[1], bottom], [xy[0], xy[1], top], radius, sections=64)
    return stem, dict(center=[float(xy[0]), float(xy[1]), bottom], radius=radius, height=top - bottom,
                      bottom_z=bottom, top_z=top)


def _section_area(cavity, z: float) -> float:
    """Area enclosed by the cavity's section with the plane at height ``z`` (oriented segments)."""
    from trimesh.intersections import mesh_plane

    seg, faces = mesh_plane(cavity, [0, 0, 1.0], [0, 0, z], return_faces=True)
    if len(seg) == 0:
        return 0.0
    p, q = seg[:, 0, :2], seg[:, 1, :2]
    n = cavity.face_normals[faces]
    flip = ((q - p) * np.stack([-n[:, 1], n[:, 0]], axis=1)).sum(axis=1) < 0
    p, q = np.where(flip[:, None], q, p), np.where(flip[:, None], p, q)
    return float(0.5 * np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]))


def _split_height(cavity, levels: int = 21) -> float:
    """z of the cavity's largest horizontal section between 20 % and 80 % of its height (the shell
    halves release best there)."""
    lo, hi = cavity.bounds[:, 2]
    zs = np.linspace(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), levels)
    return float(zs[int(np.argmax([_section_area(cavity, z) for z in zs]))])


def vertical_crossings(mesh, xy: np.ndarray) -> np.ndarray:
    """(P, k) z of every crossing of the vertical line through each xy with the mesh (NaN-padded)."""
    tri = mesh.triangles
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = (b - a)[:, :2], (c - a)[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-30
    rel = xy[:, None, :] - a[None, :, :2]  # (P, F, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (rel[..., 0] * e2[:, 1] - rel[..., 1] * e2[:, 0]) / det
        v = (e1[:, 0] * rel[..., 1] - e1[:, 1] * rel[..., 0]) / det
        inside = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
        z = a[:, 2] + u * (b - a)[:, 2] + v * (c - a)[:, 2]
    return np.where(inside, z, np.nan)


def _surface_top(cavity, xy: np.ndarray, radius: float) -> float:
    """Lowest of the cavity's top surface heights over a disk (centre + 8 on the rim)."""
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    pts = np.concatenate([xy[None], xy + radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)])
    z = vertical_crossings(cavity, pts)
    if np.any(np.all(np.isnan(z), axis=1)):
        raise DesignError("the pour or vent hole does not lie over the cavity; use a smaller pour/vent radius")
    return float(np.nanmax(z, axis=1).min())


def _hole(cavity, xy, radius: float, split_z: float, box_top: float):
    """A vertical hole from above the block down just into the cavity over the disk at ``xy``."""
    bottom = max(_surface_top(cavity, xy, radius) - 0.5e-3, split_z + 0.5e-3)
    return _cylinder([xy[0], xy[1], bottom], [xy[0], xy[1], box_top + 1e-3], radius)


def _pour_vent_xy(cavity, pour_radius: float, vent_radius: float):
    """Pour above the cavity's highest vertex; vent above the highest vertex well away from it."""
    v = cavity.vertices
    pour = v[np.argmax(v[:, 2]), :2].copy()
    half = 0.5 * float(np.min(cavity.extents[:2]))
    away = np.linalg.norm(v[:, :2] - pour, axis=1) >= pour_radius + vent_radius + 0.35 * half
    inner = np.linalg.norm(v[:, :2] - cavity.centroid[:2], axis=1) <= 0.8 * half
    cand = np.flatnonzero(away & inner)
    if cand.size == 0:
        raise DesignError("no place for a vent hole away from the pour hole; use a smaller pour_radius")
    return pour, v[cand[np.argmax(v[cand, 2])], :2].copy()


def _key_positions(block_bounds: np.ndarray, wall: float, split_z: float) -> np.ndarray:
    """Three key centres in the block's corners on the split plane (one corner left empty, so the
    halves fit together one way only)."""
    (x0, y0, _), (x1, y1, _) = block_bounds
    h = 0.5 * wall
    return np.array([[x0 + h, y0 + h, split_z], [x1 - h, y0 + h, split_z], [x1 - h, y1 - h, split_z]])


def mold_shell(cavity, *, wall: float = 10e-3, key_radius: float = 2.5e-3, key_height: float = 4e-3,
               key_clearance: float = 0.2e-3, pour_radius: float = 4e-3, vent_radius: float = 1.5e-3):
    """The two-part shell around ``cavity`` (a closed trimesh, metres): (bottom, top, info)."""
    import trimesh

    if min(wall, key_radius, key_height, pour_radius, vent_radius) <= 0 or key_clearance < 0:
        raise DesignError("mold wall, key, pour and vent sizes must be > 0 m and key_clearance >= 0 m")
    if wall < 2 * (key_radius + key_clearance) + 2e-3:
        raise DesignError(f"mold wall {wall * 1e3:.1f} mm is too thin for keys of radius {key_radius * 1e3:.1f} mm: "
                          f"use wall >= 2 (key radius + clearance) + 2 mm")
    bounds = cavity.bounds + np.array([[-wall] * 3, [wall] * 3])
    split_z = _split_height(cavity)
    pour_xy, vent_xy = _pour_vent_xy(cavity, pour_radius, vent_radius)
    pour = _hole(cavity, pour_xy, pour_radius, split_z, bounds[1, 2])
    vent = _hole(cavity, vent_xy, vent_radius, split_z, bounds[1, 2])
    block = _bool("difference", [trimesh.creation.box(bounds=bounds), cavity, pour, vent])
    pad = np.array([[-1e-3, -1e-3, 0.0], [1e-3, 1e-3, 0.0]])
    lower = trimesh.creation.box(bounds=np.array([[*bounds[0, :2], bounds[0, 2] - 1e-3], [*bounds[1, :2], split_z]]) + pad)
    upper = trimesh.creation.box(bounds=np.array([[*bounds[0, :2], split_z], [*bounds[1, :2], bounds[1, 2] + 1e-3]]) + pad)
    keys = _key_positions(bounds, wall, split_z)
    pins = [_cylinder(k - [0, 0, key_height], k + [0, 0, key_height], key_radius) for k in keys]
    holes = [_cylinder(k - [0, 0, 1e-3], k + [0, 0, key_height + key_clearance], key_radius + key_clearance)
             for k in keys]
    bottom = _bool("union", [_bool("intersection", [block, lower]), *pins])
    top = _bool("difference", [_bool("intersection", [block, upper]), *holes])
    info = dict(split_plane_z=split_z, wall=wall, keys=keys.tolist(), key_radius=key_radius,
                key_height=key_height, key_clearance=key_clearance,
                pour=dict(center=[*pour_xy.tolist(), float(bounds[1, 2])], radius=pour_radius),
                vent=dict(center=[*vent_xy.tolist(), float(bounds[1, 2])], radius=vent_radius))
    return bottom, top, info


MARKER_NOTE = ("face_centroid: the IPAM end's attachment face centroid on the rest shape (as report.md's IPAM "
               "ends); position: the boss tip, marker_height proud of it along the face normal")
SEAT_NOTE = ("a stem under the core, where the air tubes leave the device: the core stands on its flat "
             "bottom (no supports); the inner membrane keeps an opening of this size there. IPAM ends in "
             "covers_ipam_ends lie on it: their end caps are glued to the plug, their positions are in ipam_markers")
PRINTING = dict(core="as it stands, on the seat's flat bottom", shell_bottom="as it stands, outer face down "
                "(its pins stick up from the split face)", shell_top="split face down as written, or turned over "
                "(outer face down) so that the cavity opens upward")


def _scale_info(value, s: float):
    """Scale every length in a sidecar entry (nested dicts/lists of floats) by ``s``."""
    if isinstance(value, dict):
        return {k: (v if k in ("ipam", "end", "face") else _scale_info(v, s)) for k, v in value.items()}
    if isinstance(value, list):
        return [_scale_info(v, s) for v in value]
    return float(value) * s if isinstance(value, (float, np.floating)) else value


def mold_set(design: Design, *, units: str = "mm", layer_thickness: float = 5e-3, marker_height: float = 2e-3,
             marker_radius: float = 3e-3, seat_radius: float = 25e-3, seat_height: float = 5e-3,
             **shell_options) -> MoldSet:
    """The printable molds of a design in ``units`` (mm, cm, m or in): the core with IPAM bosses and
    a flat seat (:func:`core_seat`), and the two-part shell whose cavity is the rest shape offset by
    ``layer_thickness`` (m). Other sizes (``wall``, ``key_radius``, ``key_height``,
    ``key_clearance``, ``pour_radius``, ``vent_radius``) are in metres, see :func:`mold_shell`."""
    if units not in UNIT_SCALES:
        raise DesignError(f"mold units must be one of {sorted(UNIT_SCALES)}, got {units!r}")
    check_mold_lengths(equivalent_radius(design.rest), layer_thickness=layer_thickness, marker_height=marker_height)
    s = UNIT_SCALES[units]
    core, markers, seat = mold_core(design, marker_height=marker_height, marker_radius=marker_radius,
                                    seat_radius=seat_radius, seat_height=seat_height)
    cavity = outer_mold(design, layer_thickness).to_trimesh()
    bottom, top, shell_info = mold_shell(cavity, **shell_options)
    for m in (core, bottom, top, cavity):
        m.apply_scale(s)
    info = dict(units=units, scale_from_metres=s, layer_thickness=layer_thickness * s,
                marker_height=marker_height * s, marker_radius=marker_radius * s,
                ipam_markers=_scale_info(markers, s), ipam_markers_note=MARKER_NOTE,
                core_seat={**_scale_info(seat, s), "note": SEAT_NOTE}, shell=_scale_info(shell_info, s),
                printing=PRINTING,
                cavity="the membrane's outer surface: the rest shape moved radially outward by layer_thickness")
    molds = MoldSet(units=units, core=core, shell_bottom=bottom, shell_top=top, cavity=cavity, info=info)
    info["parts"] = {name: dict(file=f"{name}_{units}.stl", extents=[float(e) for e in m.extents],
                                bounds=m.bounds.tolist(), volume=float(m.volume), watertight=bool(m.is_watertight))
                     for name, m in molds.parts().items()}
    return molds
