"""Regions of the membrane whose E t a calibration fits on its own (``regions=`` of ``calibrate``).

The paper (section V-D) names where the built membrane differs from one uniform silicone: the
silicone between the jamming cells and the glue that holds them (``cell_boundaries``), the thick plug
about 5 cm across where the air tubes leave the device (``plug``), and stiffness varying across the
surface (``patches:N``, N patches of about equal size). A region is a set of rest faces; its
parameter ``region_stretch[name]`` multiplies E t on its faces (regions that overlap multiply).
"""

from __future__ import annotations

import numpy as np

from ..display import Design
from ..errors import DesignError
from ..molds import seat_place

__all__ = ["REGION_KINDS", "PLUG_RADIUS", "region_faces", "face_scale"]

#: the regions ``calibrate`` knows by name
REGION_KINDS = {
    "plug": "the underside faces within PLUG_RADIUS of the molds' seat axis, where the air tubes leave the device",
    "cell_boundaries": "the faces on either side of a jamming cell's edge (the silicone between cells, the glue)",
    "patches:N": "N patches of about equal size covering the membrane (N = 2..32)",
}
#: the plug's radius, m (the paper: a plug of about 5 cm diameter)
PLUG_RADIUS = 25e-3


def _plug(design: Design) -> np.ndarray:
    """Faces of the underside within ``PLUG_RADIUS`` (horizontally) of the seat axis the molds use."""
    rest = design.rest
    c = rest.face_centroids()
    ends = c[[f for ip in design.ipams for f in (ip.face_a, ip.face_b)]].reshape(-1, 3)
    xy, _ = seat_place(rest.to_trimesh(), ends, seat_radius=PLUG_RADIUS)
    low = c[:, 2] < rest.centroid()[2]
    near = np.linalg.norm(c[:, :2] - xy[None], axis=1) <= PLUG_RADIUS
    faces = np.flatnonzero(low & near)
    if faces.size == 0:  # a coarse mesh: the face nearest the seat's axis on the underside
        faces = np.array([int(np.argmin(np.where(low, np.linalg.norm(c[:, :2] - xy[None], axis=1), np.inf)))])
    return faces


def _cell_boundaries(design: Design) -> np.ndarray:
    """The faces on either side of every edge between a cell's face and a face of another cell or none."""
    if not design.cells:
        raise DesignError("calibrate regions: the design has no jamming cells, so no cell_boundaries region; "
                          "use plug or patches:N")
    cell = design.face_cell()
    adj = design.rest.topology.faces  # (E, 2) the two faces of each edge
    edge = cell[adj[:, 0]] != cell[adj[:, 1]]
    return np.unique(adj[edge])


def _patches(design: Design, n: int) -> np.ndarray:
    """(F,) patch of every face: farthest-point seeds on the face directions from the centroid (the
    first the highest face), each face given to its nearest seed."""
    c = design.rest.face_centroids() - design.rest.centroid()
    u = c / np.linalg.norm(c, axis=1, keepdims=True)
    seeds = [int(np.argmax(u[:, 2]))]
    for _ in range(n - 1):
        seeds.append(int(np.argmin(np.max(u @ u[seeds].T, axis=1))))
    return np.argmax(u @ u[seeds].T, axis=1)


def region_faces(design: Design, regions) -> dict:
    """{name: (n,) sorted face indices} of ``regions``: names of ``REGION_KINDS`` (``"patches:N"`` gives
    ``patch0`` .. ``patch{N-1}``), or a dict {name: face indices} of one's own. Errors are one line."""
    if regions is None:
        return {}
    if isinstance(regions, dict):
        out = {}
        for name, f in regions.items():
            arr = np.unique(np.asarray(f, dtype=np.int64).reshape(-1))
            if arr.size == 0 or arr.min() < 0 or arr.max() >= design.rest.n_faces:
                raise DesignError(f"calibrate region {name!r}: give face indices in [0, {design.rest.n_faces}) "
                                  f"(at least one)")
            out[str(name)] = arr
        return out
    names = (regions,) if isinstance(regions, str) else tuple(regions)
    out = {}
    for name in names:
        if name == "plug":
            out[name] = _plug(design)
        elif name == "cell_boundaries":
            out[name] = _cell_boundaries(design)
        elif isinstance(name, str) and name.startswith("patches:"):
            try:
                n = int(name.split(":", 1)[1])
            except ValueError:
                n = -1
            if not 2 <= n <= 32:
                raise DesignError(f"calibrate region {name!r}: give patches:N with N from 2 to 32")
            label = _patches(design, n)
            out.update({f"patch{k}": np.flatnonzero(label == k) for k in range(n)})
        else:
            raise DesignError(f"calibrate region {name!r} is not known; choose from {', '.join(REGION_KINDS)} "
                              f"(or give {{name: face indices}})")
    if not out:
        raise DesignError("calibrate regions: none given; choose from " + ", ".join(REGION_KINDS))
    return out


def face_scale(design: Design, regions: dict, values) -> np.ndarray:
    """(F,) the design's multiplier of E t per face with each region's fitted multiplier ``values``
    (in the order of ``regions``) applied on its faces."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size != len(regions):
        raise DesignError(f"region_stretch has {v.size} values for {len(regions)} regions: a calibration of "
                          f"other regions")
    if not np.all(np.isfinite(v) & (v > 0)):
        raise DesignError(f"region_stretch values must be positive numbers, got {v.tolist()}")
    s = np.ones(design.rest.n_faces) if design.stretch_scale is None else design.stretch_scale.copy()
    for (name, faces), x in zip(regions.items(), v):
        faces = np.asarray(faces, dtype=np.int64)
        if faces.size and (faces.min() < 0 or faces.max() >= design.rest.n_faces):
            raise DesignError(f"calibration region {name!r} names faces beyond this design's {design.rest.n_faces}: "
                              f"a calibration of another design")
        s[faces] *= x
    return s
