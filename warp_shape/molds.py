"""Fabrication molds (paper section V-D): inner and outer membrane molds from the rest shape.

The inner mold is the rest shape with a small pyramid marker raised on every IPAM attachment face
(where the actuator end caps are glued). The outer mold is the rest shape moved radially outward by
the jamming-layer thickness. Both are single closed, outward-wound meshes (watertight STL).
"""

from __future__ import annotations

import numpy as np

from .design import Design
from .errors import DesignError
from .mesh import TriMesh

__all__ = ["inner_mold", "outer_mold"]


def inner_mold(design: Design, marker_height: float = 2e-3) -> TriMesh:
    """Rest shape with a pyramid marker (height ``marker_height`` m) on each IPAM end face."""
    if marker_height < 0:
        raise DesignError(f"marker_height must be >= 0 m, got {marker_height}")
    rest = design.rest
    v = [rest.vertices]
    faces = rest.faces.copy()
    keep = np.ones(rest.n_faces, dtype=bool)
    extra = []
    n = rest.n_vertices
    normals = rest.face_normals()
    ends = sorted({f for ip in design.ipams for f in (ip.face_a, ip.face_b)})
    for f in ends:
        a, b, c = rest.faces[f]
        apex = rest.vertices[[a, b, c]].mean(axis=0) + marker_height * normals[f]
        v.append(apex[None, :])
        keep[f] = False
        extra += [[a, b, n], [b, c, n], [c, a, n]]
        n += 1
    all_faces = np.concatenate([faces[keep], np.array(extra, dtype=np.int32).reshape(-1, 3)])
    return TriMesh(np.concatenate(v), all_faces)


def outer_mold(design: Design, layer_thickness: float = 5e-3) -> TriMesh:
    """Rest shape moved radially outward (from its volume centroid) by ``layer_thickness`` m."""
    if not layer_thickness > 0:
        raise DesignError(f"layer_thickness must be > 0 m, got {layer_thickness}")
    rest = design.rest
    c = rest.centroid()
    d = rest.vertices - c
    r = np.linalg.norm(d, axis=1, keepdims=True)
    return TriMesh(c + d * (1.0 + layer_thickness / r), rest.faces)
