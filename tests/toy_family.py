"""A toy second actuator family, defined and registered outside the package: a tendon, a linear
spring between two membrane vertices whose rest length is its control.

Force on vertex b: -k (L - L_r) d / L (d = x_b - x_a, L = |d|, L_r the rest length), energy
k (L - L_r)^2 / 2. Its neutral control is the current length (no force)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from warp_shape.force_family import SCENE_NAMESPACE as NS
from warp_shape.force_family import ActuatorFamily, SceneAttribute
from warp_shape.errors import DesignError
from warp_shape.physics.springs import spring_rows_np


@dataclass(frozen=True)
class Tendon:
    """A tendon between rest-mesh vertices ``vertices`` = (a, b)."""

    vertices: tuple
    stiffness: float  # N/m
    rest_length: float  # m, its control when a simulation starts


def add_tendon(design, a, b, stiffness: float = 20.0, rest_length: float | None = None) -> int:
    """Add a tendon between vertices a and b of ``design`` (rest length None: their rest distance)."""
    a, b = design.check_vertex(a, "tendon vertex a"), design.check_vertex(b, "tendon vertex b")
    if a == b:
        raise DesignError(f"tendon ends coincide (both at vertex {a}); join two different vertices")
    if not stiffness > 0:
        raise DesignError(f"tendon stiffness must be > 0 N/m, got {stiffness}")
    x = design.rest.vertices
    rest = float(np.linalg.norm(x[b] - x[a])) if rest_length is None else float(rest_length)
    return design.add_element("tendon", Tendon((a, b), float(stiffness), rest))


@wp.kernel
def eval_tendon_kernel(pairs: wp.array(dtype=wp.vec2i), stiffness: wp.array(dtype=Any), x: wp.array2d(dtype=Any),
                       rest: wp.array2d(dtype=wp.float64), enabled: wp.array2d(dtype=wp.int32),
                       f: wp.array2d(dtype=Any)):
    w, i = wp.tid()
    if enabled[w, i] == 0:
        return
    p = pairs[i]
    d = x[w, p[1]] - x[w, p[0]]
    length = wp.length(d)
    k = stiffness[i]
    fa = d * (k * (length - type(k)(rest[w, i])) / length)  # pulls a towards b when stretched
    wp.atomic_add(f, w, p[0], fa)
    wp.atomic_sub(f, w, p[1], fa)


def _lengths(x: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[:, pairs[:, 1]] - x[:, pairs[:, 0]], axis=-1)


class TendonFamily(ActuatorFamily):
    name = "tendon"
    summary = "a linear spring between two vertices with a controllable rest length (test toy)"
    label, plural = "tendon", "tendons"
    control_unit, control_name = "m", "rest length"
    owner = "toy_family.add_tendon"
    scene_prim = "Tendons"
    scene_attributes = (SceneAttribute(f"{NS}:vertices", "int2[]", "vertices", 2, True),
                        SceneAttribute(f"{NS}:stiffness", "double[]", "stiffness", 1, True),
                        SceneAttribute(f"{NS}:restLength", "double[]", "rest_length", 1, True))
    history_columns = ("tendon{i}_rest_length_m", "tendon{i}_length_m")
    color = (0.8, 0.2, 0.1)
    differentiable = True  # its kernel has Warp's adjoint: ws.gradient replays through it
    parameters = {"stiffness": "N/m"}

    def host_arrays(self, design) -> dict:
        ts = design.elements(self.name)
        return dict(pairs=np.array([t.vertices for t in ts], dtype=np.int64).reshape(-1, 2),
                    stiffness=np.array([t.stiffness for t in ts], dtype=np.float64),
                    rest_length=np.array([t.rest_length for t in ts], dtype=np.float64))

    def device_arrays(self, host, arr) -> dict:
        return dict(pairs=arr(host["pairs"].astype(np.int32), wp.vec2i), stiffness=arr(host["stiffness"]))

    def rest_controls(self, host):
        return host["rest_length"]

    def eval_forces(self, model, state, control, x, v, f, launch):
        n = model.host.count(self.name)
        if not n:
            return
        dev = model.actuators[self.name]
        launch(eval_tendon_kernel, (x.shape[0], n),
               [dev["pairs"], dev["stiffness"], x, control.values[self.name], control.enabled[self.name], f])

    def energy(self, host, x, controls, enabled):
        e = host["stiffness"] * (_lengths(x, host["pairs"]) - controls) ** 2
        return 0.5 * np.sum(e * enabled, axis=1)

    def stiffness_rows(self, stiff, damp, host, inv_m, inv_sqrt):
        p, k = host["pairs"], host["stiffness"]
        spring_rows_np(stiff, p[:, 0], p[:, 1], np.broadcast_to(k, (stiff.shape[0], k.size)), inv_m, inv_sqrt)

    def operator_terms(self, xT, host):
        p, k = host["pairs"], host["stiffness"]
        if not len(k):
            return None
        d = xT[:, p[:, 1]] - xT[:, p[:, 0]]
        return p[:, 0], p[:, 1], k, k, d / np.sqrt((d * d).sum(axis=0))

    def storable_values(self, host):
        return {"stiffness": host["stiffness"], "rest_length": host["rest_length"]}

    def observe(self, dev, x, sampled, centroids, target_centroids, controls):
        return dict(lengths=_lengths(x, dev.actuators[self.name]["pairs"]))

    def history_row(self, observed, controls, w, host):
        row = {}
        for i in range(len(host["stiffness"])):
            row[f"tendon{i}_rest_length_m"] = controls[w, i]
            row[f"tendon{i}_length_m"] = observed["lengths"][w, i]
        return row

    def neutral_controls(self, host, observed, controls):
        return observed["lengths"]

    def curve_ends(self, design, positions):
        pairs = np.array([t.vertices for t in design.elements(self.name)], dtype=np.int64)
        return np.asarray(positions)[..., pairs, :]  # (..., n, 2, 3)

    def check_scene_values(self, design, values):
        bad = np.flatnonzero(((values["vertices"] < 0) | (values["vertices"] >= design.rest.n_vertices)).any(axis=1))
        return f"tendon {int(bad[0])} joins vertices out of range" if bad.size else None

    def add_from_scene(self, design, values, i):
        a, b = (int(v) for v in values["vertices"][i])
        add_tendon(design, a, b, float(values["stiffness"][i]), float(values["rest_length"][i]))


TENDON = TendonFamily()
