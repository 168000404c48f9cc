"""A passive force family defined and registered outside the package: anchor springs, each a linear
spring from a membrane vertex to a fixed point in space, with a rest length taken from the rest
shape (the distance from the vertex's rest position to its anchor, times ``slack``).

Force on vertex a: -k (L - L_r) d / L (d = x_a - p, L = |d|), energy k (L - L_r)^2 / 2, with
L_r = slack |rest_a - p|. Its parameters for the adjoint are the stiffness k (N/m) and the anchor
points p (m); the rest length is derived from the rest shape on the device (``build``), so the
gradient with respect to the rest positions flows through it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from warp_shape.errors import DesignError
from warp_shape.force_family import ForceFamily
from warp_shape.physics.springs import spring_rows_np


@dataclass(frozen=True)
class Anchor:
    """A spring from rest-mesh vertex ``vertex`` to the fixed point ``point`` (m)."""

    vertex: int
    point: tuple
    stiffness: float  # N/m
    slack: float  # rest length / rest distance


def add_anchor(design, vertex, point, stiffness: float = 50.0, slack: float = 1.0) -> int:
    """Anchor vertex ``vertex`` of ``design`` to ``point`` (3,) m by a spring of ``stiffness`` N/m."""
    vertex = design.check_vertex(vertex, "anchor vertex")
    p = np.asarray(point, dtype=np.float64).reshape(3)
    if not (stiffness > 0 and np.all(np.isfinite(p))):
        raise DesignError(f"an anchor needs stiffness > 0 N/m and a finite point, got {stiffness}, {p}")
    return design.add_element("anchor", Anchor(vertex, tuple(p), float(stiffness), float(slack)))


@wp.kernel
def anchor_rest_kernel(vertex: wp.array(dtype=wp.int32), point: wp.array(dtype=Any), slack: wp.array(dtype=Any),
                       rest: wp.array(dtype=Any), rest_length: wp.array(dtype=Any)):
    i = wp.tid()
    rest_length[i] = slack[i] * wp.length(rest[vertex[i]] - point[i])


@wp.kernel
def anchor_force_kernel(vertex: wp.array(dtype=wp.int32), point: wp.array(dtype=Any),
                        stiffness: wp.array(dtype=Any), rest_length: wp.array(dtype=Any), x: wp.array2d(dtype=Any),
                        f: wp.array2d(dtype=Any)):
    w, i = wp.tid()
    a = vertex[i]
    d = x[w, a] - point[i]
    length = wp.length(d)
    wp.atomic_add(f, w, a, d * (-stiffness[i] * (length - rest_length[i]) / length))


@wp.kernel
def anchor_diagonal_kernel(vertex: wp.array(dtype=wp.int32), stiffness: wp.array(dtype=Any),
                           diag: wp.array2d(dtype=Any)):
    w, i = wp.tid()
    wp.atomic_add(diag, w, vertex[i], stiffness[i])


class AnchorFamily(ForceFamily):
    name = "anchor"
    summary = "a linear spring from a vertex to a fixed point (test toy)"
    label, plural = "anchor", "anchors"
    owner = "anchor_family.add_anchor"
    differentiable = True
    parameters = {"stiffness": "N/m", "point": "m"}
    rigid_invariant = False  # it holds the membrane to points in space

    def host_arrays(self, design) -> dict:
        els = design.elements(self.name)
        vertex = np.array([e.vertex for e in els], dtype=np.int64)
        point = np.array([e.point for e in els], dtype=np.float64).reshape(-1, 3)
        slack = np.array([e.slack for e in els], dtype=np.float64)
        rest = slack * np.linalg.norm(design.rest.vertices[vertex] - point, axis=1)
        return dict(vertex=vertex, point=point, slack=slack, rest_length=rest,
                    stiffness=np.array([e.stiffness for e in els], dtype=np.float64))

    def device_arrays(self, host, arr) -> dict:
        vec = wp.types.vector(3, arr(np.zeros(1)).dtype)
        return dict(vertex=arr(host["vertex"].astype(np.int32), wp.int32), point=arr(host["point"], vec),
                    stiffness=arr(host["stiffness"]), slack=arr(host["slack"]), rest_length=arr(host["rest_length"]))

    def build(self, model, rest, launch):
        dev = model.actuators[self.name]
        launch(anchor_rest_kernel, len(dev["slack"]), [dev["vertex"], dev["point"], dev["slack"], rest,
                                                       dev["rest_length"]])

    def eval_forces(self, model, state, control, x, v, f, launch):
        n = model.host.count(self.name)
        if not n:
            return
        dev = model.actuators[self.name]
        launch(anchor_force_kernel, (x.shape[0], n), [dev["vertex"], dev["point"], dev["stiffness"],
                                                      dev["rest_length"], x, f])

    def diagonal_stiffness(self, model, state, diag, launch, control=None):
        dev = model.actuators[self.name]
        launch(anchor_diagonal_kernel, (diag.shape[0], len(dev["stiffness"])), [dev["vertex"], dev["stiffness"], diag])

    def energy(self, host, x, controls, enabled):
        length = np.linalg.norm(x[:, host["vertex"]] - host["point"], axis=-1)
        return 0.5 * np.sum(host["stiffness"] * (length - host["rest_length"]) ** 2, axis=1)

    def stiffness_rows(self, stiff, damp, host, inv_m, inv_sqrt):
        # a spring to a fixed point: its row is the vertex's own (k / m); spring_rows_np on (a, a) gives 4 k / m, a
        # safe over-estimate
        v, k = host["vertex"], host["stiffness"]
        spring_rows_np(stiff, v, v, np.broadcast_to(k, (stiff.shape[0], k.size)), inv_m, inv_sqrt)

    def storable_values(self, host):
        return {"stiffness": host["stiffness"]}


ANCHOR = AnchorFamily()
