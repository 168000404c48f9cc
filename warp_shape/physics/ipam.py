"""IPAM actuators, the first actuator family: launch wrapper and the model's host-side terms (energy,
stability rows and operator, observation, record, scene attributes, neutral control).

The law itself (lengths, natural length, axial force, its inverse) is in ``ipam_law``, free of Warp
kernels, so the host-side ``Design`` can use it."""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from warp_shape.kernels import adjoint as ka
from warp_shape.kernels import ipam as kip

from ..force_family import ACTUATOR_FAMILIES, SCENE_NAMESPACE as NS, ActuatorFamily, SceneAttribute
from ..limits import MAX_IPAMS
from .ipam_law import axial_force_np, centroid_distances_np, natural_length_np, pressure_for_length_np
from .springs import spring_rows_np

__all__ = ["IpamFamily", "IPAM", "IPAM_ATTRIBUTES", "ipam_energy_np", "ipam_rows_np",
           "ipam_operator_terms"]

#: The Ipams prim: per-IPAM attributes, one element per IPAM (``pairs`` / ``offsets``: three).
IPAM_ATTRIBUTES = (
    SceneAttribute(f"{NS}:faces", "int2[]", "faces", 2, True),
    SceneAttribute(f"{NS}:stiffness", "double[]", "stiffness", 1, True),
    SceneAttribute(f"{NS}:area", "double[]", "area", 1, True),
    SceneAttribute(f"{NS}:areaOverStiffness", "double[]", "area_over_stiffness", 1, False),
    SceneAttribute(f"{NS}:freeLength", "double[]", "free_length", 1, True),
    SceneAttribute(f"{NS}:restLength", "double[]", "rest_length", 1, False),
    SceneAttribute(f"{NS}:pressureLimits", "double2[]", "pressure_limits", 2, True),
    SceneAttribute(f"{NS}:damping", "double[]", "damping", 1, True),
    SceneAttribute(f"{NS}:pairs", "int2[]", "pairs", 2, False),
    SceneAttribute(f"{NS}:offsets", "double[]", "offsets", 1, False),
)


def ipam_energy_np(x: np.ndarray, a: dict, pressure: np.ndarray, enabled: np.ndarray | None = None) -> np.ndarray:
    """(W,) elastic energy of the IPAM sub-springs in J at positions x (W, V, 3) and gauge pressures
    (W, n) (``a``: the IPAM host arrays, ``HostModel.actuators["ipam"]``): three springs of stiffness
    k/3 each, natural length L_n + the sub-spring's rest offset; none from an IPAM masked out of a
    world (``enabled`` (W, n) bool False)."""
    pairs = a["sub_pairs"]
    natural = natural_length_np(a["free_length"], a["area_over_k"], pressure)
    natural = np.repeat(natural, 3, axis=1) + a["sub_offsets"]
    d = np.linalg.norm(x[:, pairs[:, 1]] - x[:, pairs[:, 0]], axis=-1)
    e = np.repeat(a["stiffness"] / 3.0, 3) * (d - natural) ** 2
    if enabled is not None:
        e = e * np.repeat(np.asarray(enabled, dtype=np.float64), 3, axis=1)
    return 0.5 * np.sum(e, axis=1)


def ipam_rows_np(stiff: np.ndarray, damp: np.ndarray, a: dict, inv_m: np.ndarray, inv_sqrt: np.ndarray) -> None:
    """Add the sub-springs' Gershgorin stiffness rows to stiff (W, V) and their dampers' rows to damp."""
    W = stiff.shape[0]
    pairs = a["sub_pairs"]
    k_sub = np.repeat(a["stiffness"] / 3.0, 3)
    c_sub = np.repeat(a["damping"], 3)
    spring_rows_np(stiff, pairs[:, 0], pairs[:, 1], np.broadcast_to(k_sub, (W, k_sub.size)), inv_m, inv_sqrt)
    spring_rows_np(damp, pairs[:, 0], pairs[:, 1], np.broadcast_to(c_sub, (W, c_sub.size)), inv_m, inv_sqrt)


def ipam_operator_terms(xT: np.ndarray, a: dict):
    """(a, b, axial k, transverse k, directions (3, n)) of the sub-springs for the elastic operator at
    positions xT (3, V). The transverse stiffness k |1 - L_n / L| is bounded by k while
    0 <= L_n <= 2 L (as in the Gershgorin bound), so k is used."""
    pairs = a["sub_pairs"]
    dp = xT[:, pairs[:, 1]] - xT[:, pairs[:, 0]]
    lp = np.maximum(np.sqrt((dp * dp).sum(axis=0)), 1e-300)
    k_sub = np.repeat(a["stiffness"] / 3.0, 3)
    return pairs[:, 0], pairs[:, 1], k_sub, k_sub, dp / lp


class IpamFamily(ActuatorFamily):
    """Inverse pneumatic artificial muscles (``Design.add_ipam``): three sub-springs between two faces
    whose natural length L_n = L0 + (A/k) P follows a gauge pressure P, the control."""

    name = "ipam"
    summary = "inverse pneumatic artificial muscles between two faces, controlled by gauge pressure"
    label, plural = "IPAM", "IPAMs"
    control_unit = "Pa"
    control_name, limits_name = "pressure", "pressure_limits"
    owner = "Design.add_ipam"
    always = True
    scene_prim = "Ipams"
    scene_attributes = IPAM_ATTRIBUTES
    max_count, count_hint = MAX_IPAMS, " (the paper's displays have 4-20)"
    history_columns = ("ipam{i}_pressure_pa", "ipam{i}_length_m", "ipam{i}_target_length_m", "ipam{i}_force_n",
                       "ipam{i}_strain")
    differentiable = True
    parameters = {"stiffness": "N/m", "area": "m^2"}
    controls_gradient = "ipam_pressures"

    def host_arrays(self, design) -> dict:
        ips = design.ipams
        return dict(
            faces=np.array([[ip.face_a, ip.face_b] for ip in ips], dtype=np.int64).reshape(-1, 2),
            sub_pairs=np.concatenate([ip.pairs for ip in ips] or [np.zeros((0, 2))]).astype(np.int64),
            sub_offsets=np.concatenate([ip.offsets for ip in ips] or [np.zeros(0)]),
            stiffness=np.array([ip.stiffness for ip in ips], dtype=np.float64),
            area=np.array([ip.area for ip in ips], dtype=np.float64),
            derived=np.array([ip.free_length_is_rest for ip in ips], dtype=np.int64),
            area_over_k=np.array([ip.area_over_stiffness for ip in ips], dtype=np.float64),
            free_length=np.array([ip.free_length for ip in ips], dtype=np.float64),
            damping=np.array([ip.damping for ip in ips], dtype=np.float64),
            limits=np.array([ip.pressure_limits for ip in ips], dtype=np.float64).reshape(-1, 2))

    def device_arrays(self, host: dict, arr) -> dict:
        return dict(sub_pairs=arr(host["sub_pairs"].astype(np.int32), wp.vec2i),
                    faces=arr(host["faces"].astype(np.int32), wp.vec2i), derived=arr(host["derived"].astype(np.int32),
                                                                                   wp.int32),
                    free_fixed=arr(host["free_length"]),
                    **{k: arr(host[k]) for k in ("sub_offsets", "stiffness", "area", "area_over_k", "free_length",
                                                  "damping")})

    def build(self, model, rest, launch) -> None:
        """The sub-springs' offsets, L0 where it is the rest centroid distance and A / k from the stiffness,
        the area and the rest positions (``Design.add_ipam``'s rule, on the device)."""
        dev = model.actuators[self.name]
        launch(ka.build_ipams_kernel, 3 * model.host.count(self.name),
               [model.faces, dev["faces"], dev["sub_pairs"], dev["free_fixed"], dev["derived"], dev["stiffness"],
                dev["area"], rest, dev["sub_offsets"], dev["free_length"], dev["area_over_k"]])

    def rest_controls(self, host: dict) -> np.ndarray:
        return np.zeros(len(host["faces"]))

    def control_limits(self, host: dict) -> np.ndarray:
        return host["limits"]

    def eval_forces(self, model, state, control, x, v, f, launch) -> None:
        """Add the sub-spring forces at (x, v) (W, V) into f (none from an IPAM masked out of a world);
        launches nothing without IPAMs. A differentiable replay's model (``differentiable``) gets the
        same kernel built with its adjoint."""
        n = model.host.count(self.name)
        if not n:
            return
        dev = model.actuators[self.name]
        kernel = ka.eval_ipam_grad_kernel if getattr(model, "differentiable", False) else kip.eval_ipam_kernel
        launch(kernel, (x.shape[0], 3 * n),
               [dev["sub_pairs"], dev["sub_offsets"], dev["stiffness"], dev["area_over_k"], dev["free_length"],
                dev["damping"], x, v, control.values[self.name], control.enabled[self.name], f])

    def energy(self, host: dict, x, controls, enabled) -> np.ndarray:
        if not len(host["faces"]):
            return np.zeros(x.shape[0])
        return ipam_energy_np(x, host, controls, enabled)

    def stiffness_rows(self, stiff, damp, host: dict, inv_m, inv_sqrt) -> None:
        if len(host["faces"]):
            ipam_rows_np(stiff, damp, host, inv_m, inv_sqrt)

    def operator_terms(self, xT, host: dict):
        return ipam_operator_terms(xT, host) if len(host["faces"]) else None

    def storable_values(self, host: dict) -> dict:
        return {"stiffness": host["stiffness"], "area / stiffness": host["area_over_k"],
                "free_length": host["free_length"], "damping": host["damping"],
                "natural length at its pressure limits": host["free_length"][:, None]
                + host["area_over_k"][:, None] * host["limits"]}

    def lengths_and_forces(self, host: dict, centroids, target_centroids, pressures):
        """(W, n) length L (distance between the end-face centroids), target length L_t (the same on the
        sampled target) and axial force k (L - L_n), L_n = L0 + (A/k) P (N, + = tension), from (W, F, 3)
        face centroids and (W, n) gauge pressures."""
        W = centroids.shape[0]
        if not len(host["faces"]):
            return np.zeros((W, 0)), np.zeros((W, 0)), np.zeros((W, 0))
        length = centroid_distances_np(centroids, host["faces"])
        target = centroid_distances_np(target_centroids, host["faces"])
        force = axial_force_np(host["stiffness"], length,
                               natural_length_np(host["free_length"], host["area_over_k"], pressures))
        return length, target, force

    def observe(self, dev, x, sampled, centroids, target_centroids, controls) -> dict:
        length, target, force = self.lengths_and_forces(dev.actuators[self.name], centroids, target_centroids, controls)
        return dict(lengths=length, target_lengths=target, forces=force)

    def history_row(self, observed: dict, controls, w: int, host: dict) -> dict:
        row, free = {}, host["free_length"]
        for i in range(len(free)):
            row[f"ipam{i}_pressure_pa"] = controls[w, i]
            row[f"ipam{i}_length_m"] = observed["lengths"][w, i]
            row[f"ipam{i}_target_length_m"] = observed["target_lengths"][w, i]
            row[f"ipam{i}_force_n"] = observed["forces"][w, i]
            row[f"ipam{i}_strain"] = (observed["lengths"][w, i] - free[i]) / free[i]
        return row

    def neutral_pressures(self, host: dict, lengths):
        """(W, n) the gauge pressures (within limits) whose natural length is the current length: an
        IPAM held at such a pressure exerts no force."""
        lim = host["limits"]
        return np.clip(pressure_for_length_np(host["free_length"], host["area_over_k"], lengths), lim[:, 0], lim[:, 1])

    def neutral_controls(self, host: dict, observed: dict, controls) -> np.ndarray:
        return self.neutral_pressures(host, observed["lengths"])

    def curve_ends(self, design, positions) -> np.ndarray:
        x = np.asarray(positions)
        ends = np.array([[ip.face_a, ip.face_b] for ip in design.ipams], dtype=np.int64).reshape(-1)
        return x[..., design.rest.faces[ends], :].mean(axis=-2)

    def curve_widths(self, design) -> np.ndarray:
        return np.array([2.0 * math.sqrt(ip.area / math.pi) for ip in design.ipams])

    def attribute_values(self, design, attr: SceneAttribute) -> np.ndarray:
        def value(ip):
            return (ip.face_a, ip.face_b) if attr.field == "faces" else getattr(ip, attr.field)

        flat = np.concatenate([np.asarray(value(ip)).reshape(-1) for ip in design.ipams])
        flat = flat.astype(np.int32 if attr.is_integer else np.float64)
        return flat if attr.width == 1 else flat.reshape(-1, attr.width)

    def check_scene_values(self, design, values: dict) -> str | None:
        faces, nf = values["faces"], design.rest.n_faces
        too_many = self.count_problem(faces.shape[0])
        if too_many:
            return too_many
        bad = np.flatnonzero(((faces < 0) | (faces >= nf)).any(axis=1))
        if bad.size:
            i = int(bad[0])
            return f"IPAM {i} joins faces {faces[i].tolist()}, out of range: the membrane has {nf} faces"
        return None

    def scene_arguments(self, values: dict, i: int) -> tuple[tuple, dict]:
        """``Design.add_ipam`` arguments of IPAM ``i`` from the required attributes' arrays: ((face_a,
        face_b), keyword arguments)."""
        faces = (int(values["faces"][i, 0]), int(values["faces"][i, 1]))
        kwargs = {}
        for attr in IPAM_ATTRIBUTES:
            if not attr.required or attr.field == "faces":
                continue
            v = values[attr.field][i]
            kwargs[attr.field] = tuple(float(p) for p in v) if attr.width > 1 else float(v)
        return faces, kwargs

    def add_from_scene(self, design, values: dict, i: int) -> None:
        (a, b), kwargs = self.scene_arguments(values, i)
        design.add_ipam(a, b, **kwargs)


#: the IPAM family, registered first
IPAM = ACTUATOR_FAMILIES.register(IpamFamily())
