"""Hyperelastic triangle membrane (SPEC section 15, docs/membrane.md): the float64 law and the force family.

A thin incompressible sheet on the triangles, in plane stress with the thickness following the stretch:
strain energy per unit rest area t W(I1), W = C1 (I1 - 3) + C2 (I1 - 3)^2 + C3 (I1 - 3)^3,
C1 = mu / 2, I1 = tr C + 1 / det C with C the 2x2 right Cauchy-Green tensor of a triangle in its
rest frame (``kernels.membrane`` holds the same law for the device). The family ``membrane`` holds one
element per face when ``Material.membrane`` is "neo_hookean" or "yeoh" (none with "springs"); the
host model then gives the edge springs no elastic stiffness (their dampers stay).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from warp_shape.kernels import membrane as km

from ..force_family import FORCE_FAMILIES, ForceFamily
from ..material import PLATE_POISSON
from .springs import spring_operator_terms, spring_rows_np

__all__ = ["MembraneFamily", "MEMBRANE", "rest_frames_np", "membrane_invariants_np", "membrane_energy_np",
           "membrane_forces_np", "thin_sphere_pressure", "principal_stretches_np", "EQUIVALENT_SPRING", "jammed_rest_np"]

#: the edge-spring stiffness that stands for a triangle in the stable-step estimate, in units of
#: 2 t dW/dI1 A0 / c^2 on each of its edges (c the rest edge length): 4 gives the incompressible
#: sheet's biaxial modulus 6 mu t on an equilateral mesh, 4/3 of the paper's lattice with E = 3 mu
EQUIVALENT_SPRING = 4.0


def rest_frames_np(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 5) float64: each triangle's Dm^-1 (d00, d01, d10, d11) in 1/m in an orthonormal frame of its
    plane (u along x1 - x0) and its area A0 in m^2, at positions x (V, 3); the host copy of
    ``kernels.membrane.rest_frame``."""
    x0, x1, x2 = (x[faces[:, k]] for k in range(3))
    e1, e2 = x1 - x0, x2 - x0
    l1 = np.linalg.norm(e1, axis=1)
    n = np.cross(e1, e2)
    a2 = np.linalg.norm(n, axis=1)
    u = e1 / l1[:, None]
    v = np.cross(n / a2[:, None], u)
    b, c = np.einsum("fi,fi->f", e2, u), np.einsum("fi,fi->f", e2, v)
    return np.stack([1.0 / l1, -b / (l1 * c), np.zeros_like(l1), 1.0 / c, 0.5 * a2], axis=1)


def _columns(x: np.ndarray, faces: np.ndarray, rest: np.ndarray):
    """F's columns (fa, fb), each (W, F, 3), at positions x (W, V, 3)."""
    x0 = x[:, faces[:, 0]]
    e1, e2 = x[:, faces[:, 1]] - x0, x[:, faces[:, 2]] - x0
    d00, d01, d10, d11 = (rest[..., k, None] for k in range(4))
    return e1 * d00 + e2 * d10, e1 * d01 + e2 * d11


def membrane_invariants_np(x: np.ndarray, faces: np.ndarray, rest: np.ndarray):
    """(I1, det C), each (W, F), of every triangle at positions x (W, V, 3); rest (F, 5) or per world
    (W, F, 5)."""
    fa, fb = _columns(x, faces, rest)
    c00, c01, c11 = (fa * fa).sum(-1), (fa * fb).sum(-1), (fb * fb).sum(-1)
    det = c00 * c11 - c01 * c01
    return c00 + c11 + 1.0 / det, det


def principal_stretches_np(x: np.ndarray, faces: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(W, F, 2) the in-plane principal stretches (smaller first) of every triangle at positions x
    (W, V, 3): the square roots of the eigenvalues of C. A stretch below 1 is compression, which the
    sheet resists as a solid (no wrinkling; docs/membrane.md)."""
    fa, fb = _columns(x, faces, rest)
    c00, c01, c11 = (fa * fa).sum(-1), (fa * fb).sum(-1), (fb * fb).sum(-1)
    mean, half = 0.5 * (c00 + c11), np.sqrt(0.25 * (c00 - c11) ** 2 + c01 ** 2)
    return np.sqrt(np.stack([mean - half, mean + half], axis=-1))


def membrane_energy_np(x: np.ndarray, faces: np.ndarray, rest: np.ndarray, moduli: np.ndarray,
                       relax: bool = False) -> np.ndarray:
    """(W,) membrane energy in J: sum A0 (c1 i + c2 i^2 + c3 i^3), i = I1 - 3, moduli (F, 3) = t (C1, C2, C3)
    in N/m; rest (F, 5) or per world (W, F, 5) (``jammed_rest_np``). ``relax``: the tension-field energy
    (``Material.compression``): a triangle whose minor principal stretch l2 is below l1^-1/2 wrinkles
    (I1 = l1^2 + 2 / l1, the uniaxial state of its major stretch), one with l1 <= 1 is slack (i = 0)."""
    i = membrane_invariants_np(x, faces, rest)[0] - 3.0
    if relax:
        s = principal_stretches_np(x, faces, rest)
        big, small = s[..., 1] ** 2, s[..., 0]
        i = np.where(small ** 4 * big < 1.0, big + 2.0 / np.sqrt(big) - 3.0, i)
        i = np.where(big <= 1.0, 0.0, i)
    c1, c2, c3 = moduli.T
    return np.sum(rest[..., 4] * i * (c1 + i * (c2 + i * c3)), axis=1)


def jammed_rest_np(rest: np.ndarray, jam: dict) -> np.ndarray:
    """(W, F, 5) rest frames per world: a jammed triangle's from its jam fields (``jam``: host copies of
    ``MembraneFamily.jam_fields``), its area times its moduli multiplier; the others' ``rest`` (F, 5)."""
    fields, jammed = jam["jam"], jam["jammed"].astype(bool)  # (6, W, F), (W, F)
    out = np.broadcast_to(rest, jammed.shape + (5,)).copy()
    frozen = np.moveaxis(fields[:5], 0, -1).astype(np.float64)
    frozen[..., 4] *= fields[5]
    out[jammed] = frozen[jammed]
    return out


def membrane_forces_np(x: np.ndarray, faces: np.ndarray, rest: np.ndarray, moduli: np.ndarray) -> np.ndarray:
    """(W, V, 3) membrane forces in N (the energy's negative gradient) at positions x (W, V, 3)."""
    fa, fb = _columns(x, faces, rest)
    c00, c01, c11 = ((fa * fa).sum(-1)[..., None], (fa * fb).sum(-1)[..., None], (fb * fb).sum(-1)[..., None])
    det = c00 * c11 - c01 * c01
    i = c00 + c11 + 1.0 / det - 3.0
    c1, c2, c3 = moduli.T
    s = rest[..., 4, None] * (c1[:, None] + 2.0 * c2[:, None] * i + 3.0 * c3[:, None] * i * i)
    k = 2.0 / det ** 2
    pa = 2.0 * fa - (fa * c11 - fb * c01) * k
    pb = 2.0 * fb - (fb * c00 - fa * c01) * k
    d00, d01, d10, d11 = (rest[..., j, None] for j in range(4))
    g1, g2 = (pa * d00 + pb * d01) * s, (pa * d10 + pb * d11) * s
    f = np.zeros(x.shape)
    for w in range(x.shape[0]):
        np.add.at(f[w], faces[:, 0], g1[w] + g2[w])
        np.add.at(f[w], faces[:, 1], -g1[w])
        np.add.at(f[w], faces[:, 2], -g2[w])
    return f


def thin_sphere_pressure(stretch, mu: float, thickness: float, radius: float, c2: float = 0.0, c3: float = 0.0):
    """Gauge pressure (Pa) of a thin incompressible sphere of rest radius and thickness (m) at the
    equibiaxial stretch ``stretch``: P = (t / R lambda^2) dW/dlambda with I1 = 2 lambda^2 + lambda^-4;
    neo-Hookean (c2 = c3 = 0): 2 mu (t / R)(1 / lambda - 1 / lambda^7), its limit point at 7^(1/6)."""
    lam = np.asarray(stretch, dtype=np.float64)
    i = 2.0 * lam ** 2 + lam ** -4 - 3.0
    slope = 0.5 * mu + 2.0 * c2 * i + 3.0 * c3 * i * i
    return thickness / (radius * lam ** 2) * slope * (4.0 * lam - 4.0 * lam ** -5)


def _edge_pairs(faces: np.ndarray):
    """(a, b) (3F,) the vertices of every triangle's three edges, and each edge's face (3F,)."""
    a = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    b = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    return a, b, np.tile(np.arange(len(faces)), 3)


class MembraneFamily(ForceFamily):
    """The hyperelastic membrane: one element per face of a design whose ``Material.membrane`` is
    "neo_hookean" or "yeoh". Host arrays: ``faces`` (F, 3), ``rest`` (F, 5) (``rest_frames_np``),
    ``moduli`` (F, 3) t (C1, C2, C3) in N/m; for the stable-step estimate each triangle's edges as
    springs (``EQUIVALENT_SPRING``): ``pair_a``, ``pair_b``, ``pair_face`` (3F,) and their rest lengths
    ``pair_rest`` (3F,) m, and their sum per vertex ``vertex_stiffness`` (V,) N/m (the static settle's
    preconditioner part)."""

    name = "membrane"
    summary = "a thin incompressible hyperelastic sheet (neo-Hookean / Yeoh) on the triangles"
    label, plural = "membrane triangle", "membrane triangles"
    owner = "Material (membrane, shear_modulus, yeoh_c2, yeoh_c3, thickness, compression)"
    jams = True
    # the force kernel's adjoint is Warp's, checked against central differences of the float64 law
    # (tests/test_membrane.py); the moduli, the plate stiffness and the rest frames are derived from the
    # law's constants and the rest positions on the tape (build)
    differentiable = True
    parameters = {"shear_modulus": "Pa: the sheet's shear modulus mu (C1 = mu / 2)",
                  "yeoh_c2": "Pa: the Yeoh law's C2", "yeoh_c3": "Pa: the Yeoh law's C3",
                  "thickness": "m: the sheet's thickness (its moduli and plate bending; the mass held)"}
    scalar_parameters = ("shear_modulus", "yeoh_c2", "yeoh_c3", "thickness")

    def count(self, design) -> int:
        return design.rest.n_faces if design.material.hyperelastic else 0

    def host_arrays(self, design) -> dict:
        mesh, mat = design.rest, design.material
        faces = mesh.faces.astype(np.int64)
        scale = np.ones(len(faces)) if design.stretch_scale is None else np.asarray(design.stretch_scale, float)
        moduli = mat.thickness * np.asarray(mat.yeoh_constants)[None, :] * scale[:, None]
        a, b, face = _edge_pairs(faces)
        cells = [c.faces.astype(np.int64) for c in design.cells]
        host = dict(faces=faces, rest=rest_frames_np(mesh.vertices, faces), moduli=moduli, pair_a=a, pair_b=b,
                    pair_face=face, pair_rest=np.linalg.norm(mesh.vertices[b] - mesh.vertices[a], axis=1),
                    face_edges=mesh.topology.face_edges.astype(np.int64),
                    cell_faces=np.concatenate(cells) if cells else np.zeros(0, dtype=np.int64),
                    cell_offsets=np.cumsum([0] + [len(c) for c in cells]).astype(np.int64),
                    jam_factor=np.array([mat.jam_stretch_factor]), face_scale=scale,
                    shear_modulus=np.array([mat.mu]), yeoh_c2=np.array([mat.yeoh_c2]),
                    yeoh_c3=np.array([mat.yeoh_c3]), thickness=np.array([mat.thickness]),
                    plate=np.array([mat.plate_stiffness]),
                    relax=np.array([int(mat.compression == "tension_field")]))
        k, V = self._equivalent(host), mesh.n_vertices
        host["vertex_stiffness"] = np.bincount(a, k, V) + np.bincount(b, k, V)  # the settle's preconditioner part
        return host

    def device_arrays(self, host, arr) -> dict:
        return dict(faces=arr(host["faces"].astype(np.int32), wp.vec3i), rest=arr(host["rest"]), moduli=arr(host["moduli"]),
                    vertex_stiffness=arr(host["vertex_stiffness"]),
                    cell_faces=arr(host["cell_faces"].astype(np.int32), wp.int32),
                    no_jam=arr(np.zeros((6, 1, 1))), no_jammed=arr(np.zeros((1, 1), dtype=np.int32), wp.int32),
                    **{k: arr(host[k]) for k in ("face_scale", "shear_modulus", "yeoh_c2", "yeoh_c3", "thickness",
                                                 "plate")})

    def jam_fields(self, model, worlds):
        F, dev = model.n_faces, model.device
        return dict(jam=wp.zeros((6, worlds, F), dtype=model.scalar, device=dev),
                    jammed=wp.zeros((worlds, F), dtype=wp.int32, device=dev))

    def jam(self, model, state, cell, world_mask, launch):
        host, dev, fields = model.host.actuators[self.name], model.actuators[self.name], state.family_jam[self.name]
        a, b = (int(v) for v in host["cell_offsets"][cell:cell + 2])
        if b > a:
            launch(km.jam_membrane_kernel, (state.worlds, b - a),
                   [dev["faces"], dev["cell_faces"][a:b], world_mask, model.scalar(model.jam_stretch_factor), dev["rest"],
                    state.x, fields["jam"], fields["jammed"]])

    def build(self, model, rest, launch):
        """The moduli and the plate stiffness (``plate``, the hinges' bending: ``model.hinge_bend_stiffness``)
        from the law's constants, the rest frames from the rest positions."""
        dev = model.actuators[self.name]
        n = dev["faces"].shape[0]
        launch(km.membrane_moduli_kernel, n, [dev["face_scale"], dev["shear_modulus"], dev["yeoh_c2"], dev["yeoh_c3"],
                                              dev["thickness"], dev["moduli"]])
        launch(km.membrane_plate_kernel, 1, [dev["shear_modulus"], dev["thickness"],
                                             model.scalar(3.0 / (12.0 * (1.0 - PLATE_POISSON ** 2))), dev["plate"]])
        launch(km.membrane_rest_kernel, n, [dev["faces"], rest, dev["rest"]])

    def jam_event(self, model, fields_in, fields_out, now, x, launch):
        dev, host = model.actuators[self.name], model.host.actuators[self.name]
        launch(km.jam_membrane_grad_kernel, dev["faces"].shape[0],
               [dev["faces"], now, model.scalar(float(host["jam_factor"][0])), dev["rest"], x, fields_in["jam"],
                fields_in["jammed"], fields_out["jam"], fields_out["jammed"]])

    def eval_forces(self, model, state, control, x, v, f, launch):
        if not model.host.count(self.name):
            return
        dev = model.actuators[self.name]
        fields = None if state is None else getattr(state, "family_jam", {}).get(self.name)
        jam = [1, fields["jam"], fields["jammed"]] if fields else [0, dev["no_jam"], dev["no_jammed"]]
        relax = int(model.host.actuators[self.name]["relax"][0])
        launch(km.eval_membrane_kernel, (x.shape[0], dev["faces"].shape[0]), [dev["faces"], dev["rest"], dev["moduli"], relax,
                                                                             *jam, x, f])

    def rest_controls(self, host):
        return np.zeros(len(host["faces"]))

    def energy(self, host, x, controls, enabled, jam=None):
        rest = host["rest"] if jam is None else jammed_rest_np(host["rest"], jam)
        return membrane_energy_np(x, host["faces"], rest, host["moduli"], relax=bool(host["relax"][0]))

    def _equivalent(self, host, slope_scale=None) -> np.ndarray:
        """(3F,) stiffness (N/m) of the springs standing for the triangles' edges."""
        face = host["pair_face"]
        mu_t = 2.0 * host["moduli"][face, 0] if slope_scale is None else 2.0 * slope_scale[face]
        return EQUIVALENT_SPRING * mu_t * host["rest"][face, 4] / host["pair_rest"] ** 2

    @staticmethod
    def _jam_multiplier(host, jammed) -> np.ndarray:
        """(..., 3F) the jam factor on the springs of the triangles whose three edges are jammed (a jammed
        cell's), 1 elsewhere; jammed (..., E) bool edge flags."""
        face_jammed = np.asarray(jammed, dtype=bool)[..., host["face_edges"]].all(axis=-1)
        return np.where(face_jammed[..., host["pair_face"]], host["jam_factor"][0], 1.0)

    def stiffness_rows(self, stiff, damp, host, inv_m, inv_sqrt, jammed=None):
        k = np.broadcast_to(self._equivalent(host), (stiff.shape[0], len(host["pair_face"])))
        if jammed is not None:
            k = k * self._jam_multiplier(host, jammed)
        spring_rows_np(stiff, host["pair_a"], host["pair_b"], k, inv_m, inv_sqrt)

    def operator_terms(self, xT, host, jammed=None):
        # the tangent t dW/dI1 at the current invariant (it grows with a Yeoh law's C2, C3)
        i = membrane_invariants_np(xT.T[None], host["faces"], host["rest"])[0][0] - 3.0
        c1, c2, c3 = host["moduli"].T
        slope = np.maximum(c1 + 2.0 * c2 * i + 3.0 * c3 * i * i, c1)
        k = self._equivalent(host, slope)
        if jammed is not None:
            k = k * self._jam_multiplier(host, jammed)
        k_ax, k_tr, d = spring_operator_terms(xT, host["pair_a"], host["pair_b"], k, host["pair_rest"])
        return host["pair_a"], host["pair_b"], k_ax, k_tr, d

    def diagonal_stiffness(self, model, state, diag, launch, control=None):
        dev = model.actuators[self.name]
        launch(km.add_vertex_diagonal_kernel, diag.shape, [dev["vertex_stiffness"], diag])

    def storable_values(self, host):
        return {"t C1, t C2, t C3 (membrane moduli, N/m)": host["moduli"]}


MEMBRANE = MembraneFamily()
FORCE_FAMILIES.register(MEMBRANE)
