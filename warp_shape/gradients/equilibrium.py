"""The controls' gradient at a static equilibrium, by implicit differentiation (docs/gradients.md).

At an equilibrium x*(u) of the controls u (the air and the IPAM pressures) the net force vanishes,
F(x*, u) = 0, so dx*/du = K^-1 dF/du with K = -dF/dx the stiffness (the energy's Hessian). The
derivative of an objective J(x*) is then

    dJ/du = mu^T dF/du,    K mu = dJ/dx,

one linear solve whatever the number of controls. K is applied matrix-free: K v = -(dF/dx)^T v is a
vector-Jacobian product of the force, the adjoint of one force evaluation on the replay's kernels
(``kernels/adjoint.py``, float64), and the solve is conjugate gradients preconditioned by a
per-vertex stiffness estimate, with the six rigid modes projected out (K is singular along them). A
settle started at or near the equilibrium moves along forces, which carry no net force or torque, so
its response to the controls lies in their complement: the gradient is that of the settles the
refinement runs, rigid motion included (``tests/test_equilibrium_gradient.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warp_shape.kernels import adjoint as ka

from ..errors import DesignError
from .families import ReplayFamilies
from .differentiable_replay import adjoint_argument, hinge_adjoint_launch

__all__ = ["EquilibriumGradient", "ControlGradient", "CG_TOLERANCE", "CG_MAX_ITERATIONS"]

CG_TOLERANCE = 1e-6  # the solve stops at this residual, relative to the right-hand side's
CG_MAX_ITERATIONS = 3000  # conjugate-gradient iterations at most


@dataclass
class ControlGradient:
    """d objective / d controls at an equilibrium: ``air`` per mol, ``pressures`` (n_ipam,) per Pa (zero
    where the IPAM is disabled), with the solve's ``iterations``, relative ``residual``,
    ``converged`` flag and solution ``adjoint``."""

    air: float
    pressures: np.ndarray
    iterations: int
    residual: float
    converged: bool
    adjoint: np.ndarray | None = None  # (V, 3) the multipliers mu (K mu = dJ/dx): a next solve's start


class EquilibriumGradient:
    """Force evaluations and their vector-Jacobian products on one world of ``host`` (a
    ``model.HostModel``) in float64, for the implicit gradient of an objective at an equilibrium.

    ``load(x, edge, air, pressures, enabled, controls)`` sets the point (positions (V, 3) m, at rest; edge
    fields (4, E) as a simulator state holds them, jams applied; air mol; gauge pressures (n,) Pa; enabled
    (n,) bool; other actuator families' controls {family: (n,)}, their rest controls where not given; the
    jamming families' fields ``family_jam`` {family: {field: array}} of the point's world, world axis of size 1
    kept, nothing jammed where not given); ``force()`` is the net force there, ``stiffness_product(v)`` K v, ``control_gradient(dj_dx)``
    the gradient of an objective with derivative ``dj_dx`` (V, 3) with respect to the air and the
    pressures."""

    def __init__(self, host, material, device: str = "cpu"):
        self.host, self.device = host, str(device)
        V, E, n = len(host.rest_vertices), len(host.hinges), host.n_ipams
        self.V, self.E, self.n = V, E, n
        self.hinges = wp.array(host.hinges.astype(np.int32), dtype=wp.vec4i, device=self.device)
        self.owns = wp.array(np.asarray(host.hinge_owns, dtype=np.int32), dtype=wp.int32, device=self.device)
        self.spring_damping = wp.float64(material.spring_damping)
        self.viscous_damping = wp.float64(material.viscous_damping)
        self.edge = wp.zeros((4, 1, E), dtype=wp.float64, device=self.device, requires_grad=True)
        self.xv = wp.zeros((2, 1, V), dtype=wp.vec3d, device=self.device, requires_grad=True)
        self.fg = wp.zeros((2, 1, V), dtype=wp.vec3d, device=self.device, requires_grad=True)
        self.volume = wp.zeros((1, 1), dtype=wp.float64, device=self.device, requires_grad=True)
        self.angles = wp.zeros((1, 1, E), dtype=wp.float64, device=self.device)
        self.slot = wp.zeros(1, dtype=wp.int32, device=self.device)
        # the IPAMs and every other force family, through their own launches (gradients/families.py)
        faces = wp.array(host.faces.astype(np.int32), dtype=wp.vec3i, device=self.device)
        self.fam = ReplayFamilies(host, faces, wp.float64, wp.vec3d, np.float64, self.device, "float64")
        self.controls = self.fam.controls()
        self.jam = self.fam.jam_fields()  # the jamming families' fields at the point (one world)
        self.rigid_free = all(f.rigid_invariant for f in host.families)
        self.air = 0.0
        self._launches: list = []
        self._rigid = None
        self._diag = None

    # ------------------------------------------------------------------ the point
    def load(self, x, edge, air: float, pressures, enabled=None, controls: dict | None = None,
             family_jam: dict | None = None) -> None:
        x = np.asarray(x, dtype=np.float64).reshape(self.V, 3)
        edge = np.asarray(edge, dtype=np.float64).reshape(4, self.E)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(edge)) and np.isfinite(air) and air > 0):
            raise DesignError("an equilibrium gradient needs finite positions and edge fields and air > 0")
        xv = np.zeros((2, 1, self.V, 3))
        xv[0, 0] = x
        self.xv.assign(xv)
        self.edge.assign(edge.reshape(4, 1, self.E))
        self.air = float(air)
        if self.n:
            self.controls.values["ipam"].assign(np.asarray(pressures, dtype=np.float64).reshape(1, self.n))
            on = np.ones(self.n, bool) if enabled is None else np.asarray(enabled, bool).reshape(self.n)
            self.controls.enabled["ipam"].assign(on.astype(np.int32).reshape(1, self.n))
        for fam in self.fam.controlled:  # other actuator families: the controls given, else their rest controls
            if fam.name != "ipam":
                given = (controls or {}).get(fam.name, fam.rest_controls(self.host.actuators[fam.name]))
                self.controls.values[fam.name].assign(np.asarray(given, dtype=np.float64).reshape(1, -1))
        self.fam.set_jam(self.jam, family_jam or {})
        self._forward()
        self._rigid = _rigid_basis(x)
        self._diag = self._stiffness_diagonal(edge)

    def add_to_preconditioner(self, stiffness: np.ndarray) -> None:
        """Add a per-vertex stiffness (V,) N/m to the loaded point's preconditioner: the part of a force family
        the membrane's estimate does not see (a hold, a contact), so that the solve does not slow where it is
        stiff."""
        self._diag = self._diag + np.asarray(stiffness, dtype=np.float64).reshape(self.V)

    def _forward(self) -> None:
        """One force evaluation at the point: forces without pressure and dV/dx (fg), the volume."""
        self.fg.zero_()
        self.volume.zero_()
        self._launches = [
            (ka.start_forces_kernel, self.V, [self.viscous_damping, self.xv, self.fg, self.volume]),
            (ka.hinge_grad_kernel, self.E, [self.hinges, self.owns, self.spring_damping, 0, 1, self.E, self.edge,
                                            self.xv, 0, self.fg, self.volume, self.angles, self.slot, 0])]
        self.fam.forces(self.controls, self.xv, self.fg, lambda k, dim, inputs: self._launches.append((k, dim, inputs)),
                        self.fam.jam_state(self.jam))
        for kernel, dim, inputs in self._launches:
            wp.launch(kernel, dim, inputs, device=self.device, record_tape=False)
        fg = self.fg.numpy()
        self._f, self._g = fg[0, 0].astype(np.float64), fg[1, 0].astype(np.float64)
        self._vol = float(self.volume.numpy()[0, 0])

    def gauge_pressure(self) -> float:
        return self.air * self.host.gas_rt / self._vol - self.host.atmospheric_pressure

    def force(self) -> np.ndarray:
        """(V, 3) the net force at the point, N (-dE/dx at rest)."""
        return self._f + self.gauge_pressure() * self._g

    # ------------------------------------------------------------------ products
    def force_vjp(self, lam: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """lam^T dF/dx (V, 3), lam^T dF/d air (per mol) and lam^T dF/dP (n,) at the point."""
        lam = np.asarray(lam, dtype=np.float64).reshape(self.V, 3)
        p = self.gauge_pressure()
        rt = self.host.gas_rt
        p_bar = float(np.sum(lam * self._g))
        adj = np.zeros((2, 1, self.V, 3))
        adj[0, 0], adj[1, 0] = lam, p * lam
        self.fg.grad.assign(adj)
        self.volume.grad.assign(np.array([[p_bar * (-self.air * rt / self._vol ** 2)]]))
        for a in (self.xv.grad, self.edge.grad, *(v.grad for v in self.controls.values.values())):
            a.zero_()
        for kernel, dim, inputs in reversed(self._launches):
            if kernel is ka.start_forces_kernel:  # at rest: only velocities, which carry no adjoint here
                continue
            if kernel is ka.hinge_grad_kernel:
                wp.launch(*hinge_adjoint_launch(dim, inputs), device=self.device, record_tape=False)
                continue
            wp.launch(kernel, dim, inputs, adj_inputs=[adjoint_argument(a) for a in inputs], device=self.device,
                      adjoint=True, record_tape=False)
        dx = self.xv.grad.numpy()[0, 0].astype(np.float64)
        dp = (self.controls.values["ipam"].grad.numpy()[0, :self.n].astype(np.float64) if self.n
              else np.zeros(0))
        return dx, p_bar * rt / self._vol, dp

    def project(self, v: np.ndarray) -> np.ndarray:
        """v without its rigid components (translations, rotations about the centroid; unit weights), where
        every force of the model is invariant under rigid motions (else K is not singular along them: v)."""
        if not self.rigid_free:
            return np.asarray(v, dtype=np.float64).reshape(self.V, 3)
        flat = np.asarray(v, dtype=np.float64).reshape(-1)
        return (flat - self._rigid @ (self._rigid.T @ flat)).reshape(self.V, 3)

    def stiffness_product(self, v: np.ndarray) -> np.ndarray:
        """K v = -(dF/dx)^T v, rigid modes projected out on both sides."""
        dx, _, _ = self.force_vjp(self.project(v))
        return self.project(-dx)

    def _stiffness_diagonal(self, edge: np.ndarray) -> np.ndarray:
        """(V,) a per-vertex stiffness estimate (N/m): every edge's stretch stiffness on its ends, every
        hinge's k_t / L^2 on its four vertices, every IPAM sub-spring's k / 3 on its two."""
        h = self.host.hinges
        d = np.zeros(self.V)
        np.add.at(d, h[:, 0], edge[2])
        np.add.at(d, h[:, 1], edge[2])
        kb = edge[3] / np.maximum(edge[0], 1e-12) ** 2
        for c in range(4):
            np.add.at(d, h[:, c], kb)
        if self.n:
            pairs = np.asarray(self.host.ipam_sub_pairs).reshape(-1, 2)
            k = np.repeat(np.asarray(self.host.ipam_stiffness, float) / 3.0, 3)
            np.add.at(d, pairs[:, 0], k)
            np.add.at(d, pairs[:, 1], k)
        return np.maximum(d, 1e-30)

    # ------------------------------------------------------------------ the solve
    def solve(self, rhs: np.ndarray, tolerance: float = CG_TOLERANCE, max_iterations: int = CG_MAX_ITERATIONS,
              guess: np.ndarray | None = None) -> tuple[np.ndarray, int, float, bool]:
        """mu with K mu = rhs (rigid parts of rhs removed) by preconditioned conjugate gradients, from
        ``guess`` (e.g. the solution at a nearby equilibrium) or zero: (mu, iterations, relative
        residual, converged). Stops unconverged at a direction of non-positive curvature (not a
        stable equilibrium)."""
        b = self.project(rhs)
        nb = float(np.linalg.norm(b))
        x = np.zeros_like(b)
        if nb == 0.0:
            return x, 0, 0.0, True
        inv_d = (1.0 / self._diag)[:, None]
        r = b.copy()
        if guess is not None:
            x = self.project(guess)
            r = b - self.stiffness_product(x)
            if float(np.linalg.norm(r)) > nb:  # a worse start than zero
                x, r = np.zeros_like(b), b.copy()
            elif float(np.linalg.norm(r)) <= tolerance * nb:
                return x, 0, float(np.linalg.norm(r)) / nb, True
        z = self.project(r * inv_d)
        p = z.copy()
        rz = float(np.sum(r * z))
        for it in range(1, max_iterations + 1):
            q = self.stiffness_product(p)
            curv = float(np.sum(p * q))
            if not curv > 0.0:
                return x, it, float(np.linalg.norm(r)) / nb, False
            alpha = rz / curv
            x += alpha * p
            r -= alpha * q
            res = float(np.linalg.norm(r)) / nb
            if res <= tolerance:
                return x, it, res, True
            z = self.project(r * inv_d)
            rz_new = float(np.sum(r * z))
            p = z + (rz_new / rz) * p
            rz = rz_new
        return x, max_iterations, res, False

    def control_gradient(self, dj_dx: np.ndarray, tolerance: float = CG_TOLERANCE,
                         max_iterations: int = CG_MAX_ITERATIONS, guess: np.ndarray | None = None) -> ControlGradient:
        """dJ/d(air, pressures) at the loaded equilibrium for an objective J with dJ/dx ``dj_dx`` (V, 3)
        (``guess``: a start for the solve, ``ControlGradient.adjoint`` of a nearby equilibrium)."""
        mu, it, res, ok = self.solve(dj_dx, tolerance, max_iterations, guess)
        _, d_air, d_p = self.force_vjp(mu)
        if self.n:
            d_p = d_p * self.controls.enabled["ipam"].numpy()[0, :self.n]
        return ControlGradient(air=float(d_air), pressures=d_p, iterations=it, residual=res, converged=ok, adjoint=mu)


def _rigid_basis(x: np.ndarray) -> np.ndarray:
    """(3V, 6) an orthonormal basis of the infinitesimal rigid motions of positions x (V, 3)."""
    c = x - x.mean(axis=0)
    V = len(x)
    B = np.zeros((V, 3, 6))
    for k in range(3):
        B[:, k, k] = 1.0
        axis = np.zeros(3)
        axis[k] = 1.0
        B[:, :, 3 + k] = np.cross(axis, c)
    q, _ = np.linalg.qr(B.reshape(3 * V, 6))
    return q
