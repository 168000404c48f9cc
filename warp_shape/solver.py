"""Force evaluation and time integrators.

One thin ``eval_*`` wrapper per force family; each skips work the model does not need (no IPAMs ->
no IPAM launch; k_t = 0 -> no bending launch). Wrappers take a ``launch(kernel, dim, inputs)``
callable so the same code path serves direct launches, recorded launches and graph capture.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import warp as wp

from warp_shape.kernels import bending as kb
from warp_shape.kernels import common as kc
from warp_shape.kernels import hinge as kh
from warp_shape.kernels import integrate as ki
from warp_shape.kernels import ipam as kip
from warp_shape.kernels import pressure as kp
from warp_shape.kernels import springs as ks

from .errors import DesignError
from .model import Control, Model, State, volumes_np

__all__ = ["FORCE_TERMS", "eval_forces", "eval_forces_fused", "Solver", "RK4Solver", "SemiImplicitSolver", "make_solver",
           "stable_dt_estimate", "elastic_omega2_bound", "lanczos_upper_bound",
           "INTEGRATORS"]

Launch = Callable[[wp.Kernel, tuple, list], None]

FORCE_TERMS = ("spring", "bending", "pressure", "ipam", "viscous")


# --------------------------------------------------------------------------- force families

def eval_init_viscous(model: Model, v, f, volume, launch: Launch, enabled: bool = True):
    """Start a force evaluation: f = -c_v v (or 0 without the viscous term), volume zeroed."""
    c_v = model.viscous_damping if enabled else 0.0
    launch(kc.init_forces_viscous, f.shape, [model.scalar(c_v), v, f, volume])


def eval_volume(model: Model, x, volume, launch: Launch):
    """Accumulate each world's enclosed volume (m^3, float64)."""
    launch(kp.eval_volume_kernel, (x.shape[0], model.n_faces), [model.faces, x, volume])


def eval_pressure(model: Model, x, volume, control: Control, f, launch: Launch):
    """Add the pressure force p A / 3 n_hat of every face (p gauge, from air and volume)."""
    launch(kp.eval_pressure_kernel, (x.shape[0], model.n_faces),
           [model.faces, wp.float64(model.gas_rt), wp.float64(model.atmospheric_pressure), x, volume,
            control.air, f])


def eval_springs(model: Model, state: State, x, v, f, launch: Launch):
    """Add edge spring and damper forces (jammed edges stiffened)."""
    s = model.scalar
    launch(ks.eval_spring_kernel, (x.shape[0], model.n_edges),
           [model.hinges, model.edge_stiffness, s(model.spring_damping), s(model.jam_stretch_factor), x, v,
            state.rest_length, state.jammed, f])


def eval_bending(model: Model, state: State, x, f, launch: Launch, paper: bool = False):
    """Add hinge bending forces; launches nothing when k_t = 0."""
    if not model.has_bending:
        return
    s = model.scalar
    launch(kb.eval_bending_kernel, (x.shape[0], model.n_edges),
           [model.hinges, s(model.bending_stiffness), s(model.jam_bend_factor), int(paper), x,
            state.rest_angle, state.jammed, f])


def eval_ipams(model: Model, x, v, control: Control, f, launch: Launch):
    """Add IPAM sub-spring forces; launches nothing without IPAMs."""
    if not model.has_ipams:
        return
    launch(kip.eval_ipam_kernel, (x.shape[0], 3 * model.n_ipams),
           [model.ipam_sub_pairs, model.ipam_sub_offsets, model.ipam_stiffness, model.ipam_area_over_k,
            model.ipam_free_length, model.ipam_damping, x, v, control.ipam_pressure, f])


def eval_forces(model: Model, state: State, control: Control, x, v, f, volume, launch: Launch,
                paper_bending: bool = False, terms=FORCE_TERMS):
    """Force terms at (x, v) into f (overwritten), one kernel per family; volume (W,) receives the
    enclosed volume per world. Used for per-term read-outs; steps use the fused pass below."""
    eval_init_viscous(model, v, f, volume, launch, enabled="viscous" in terms)
    if "pressure" in terms:
        eval_volume(model, x, volume, launch)
        eval_pressure(model, x, volume, control, f, launch)
    if "spring" in terms:
        eval_springs(model, state, x, v, f, launch)
    if "bending" in terms:
        eval_bending(model, state, x, f, launch, paper_bending)
    if "ipam" in terms:
        eval_ipams(model, x, v, control, f, launch)


def eval_init_step(model: Model, xv, fg, volume2d, launch: Launch):
    """Forces = -c_v v, dV/dx = 0 and every volume slot zeroed (start of a fused evaluation).
    xv and fg are packed (2, W, V) buffers: (positions, velocities) and (forces, dV/dx)."""
    _, W, V = fg.shape
    launch(kc.init_step_forces, (W * V,), [model.scalar(model.viscous_damping), W, V, xv, fg, volume2d])


def eval_hinges(model: Model, state: State, xv, fg, volume2d, slot: int, launch: Launch, paper: bool = False):
    """One fused pass over the hinges at the point xv (2, W, V): springs + dampers, bending (only
    when k_t > 0), the enclosed volume (into column ``slot`` of volume2d) and dV/dx (into fg[1]).
    Accumulates."""
    _, W, _ = xv.shape
    E = model.n_edges
    kernel = kh.eval_hinge_bending_kernel if model.has_bending else kh.eval_hinge_kernel
    launch(kernel, (W * E,),
           [model.hinges, model.hinge_owns, model.scalar(model.spring_damping), int(paper), W, E, state.edge, xv, slot,
            fg, volume2d])


def eval_forces_fused(model: Model, state: State, control: Control, fg, volume2d, launch: Launch,
                      paper_bending: bool = False):
    """Total force at the current state into fg[0] (overwritten; fg is (2, W, V), fg[1] receives
    dV/dx) through the same fused kernels as a step."""
    _, W, V = fg.shape
    eval_init_step(model, state.xv, fg, volume2d, launch)
    eval_hinges(model, state, state.xv, fg, volume2d, 0, launch, paper_bending)
    eval_ipams(model, state.x, state.v, control, fg[0], launch)
    launch(kp.finish_forces_kernel, (W * V,),
           [wp.float64(model.gas_rt), wp.float64(model.atmospheric_pressure), W, V, volume2d, 0, control.air, fg])


# --------------------------------------------------------------------------- integrators

class Solver:
    """Advances State by one internal step h with Control held constant."""

    name = "base"
    order = 0
    # dt_stable = stability_constant / (omega_max + gamma_max)
    stability_constant = 1.0

    def __init__(self, model: Model, state: State, control: Control, paper_bending: bool = False):
        self.model, self.state, self.control = model, state, control
        self.paper_bending = paper_bending
        W, V = state.x.shape
        dev = model.device
        self.fg = wp.zeros((2, W, V), dtype=model.vec3, device=dev)  # forces without pressure; dV/dx
        self.f, self.gradv = self.fg[0], self.fg[1]  # (W, V) views
        self.volume = wp.zeros((W, 4), dtype=wp.float64, device=dev)  # volume at each stage point
        # blow-up bounds, checked by the kernel that writes the new state
        rest = model.host.rest_vertices
        center = rest.mean(axis=0)
        self.size = float(2.0 * np.linalg.norm(rest - center, axis=1).max())  # m
        self.x_bound = float(np.linalg.norm(center) + 50.0 * self.size)  # |x| beyond this (m) is a blow-up
        self.status = wp.zeros(W, dtype=wp.int32, device=dev)  # (W,) worst blow-up code since last cleared

    def _check_args(self, h: float) -> list:
        """Blow-up bounds for internal step h: |x| and |v| (one mesh size per step)."""
        return [self.model.scalar(self.x_bound), self.model.scalar(self.size / h)]

    def begin(self, launch: Launch):
        """Start the first force evaluation of a step at the current state."""
        eval_init_step(self.model, self.state.xv, self.fg, self.volume, launch)

    def forces(self, xv, x, v, slot: int, launch: Launch):
        """Accumulate every force family but pressure (applied by the stage kernel) at xv = (x, v)."""
        eval_hinges(self.model, self.state, xv, self.fg, self.volume, slot, launch, self.paper_bending)
        eval_ipams(self.model, x, v, self.control, self.f, launch)

    def _pressure_args(self):
        m = self.model
        return [wp.float64(m.gas_rt), wp.float64(m.atmospheric_pressure)]

    def step(self, h: float, launch: Launch):  # pragma: no cover - abstract
        raise NotImplementedError


class SemiImplicitSolver(Solver):
    """Symplectic Euler: first order, one force evaluation per step."""

    name = "semi_implicit"
    order = 1
    stability_constant = 1.9  # omega h < 2 for the undamped oscillator

    def step(self, h: float, launch: Launch):
        st, m = self.state, self.model
        W, V = st.x.shape
        self.begin(launch)
        self.forces(st.xv, st.x, st.v, 0, launch)
        launch(ki.integrate_semi_implicit_fused, (W * V,),
               [m.inv_mass, *self._pressure_args(), m.scalar(h), W, V, *self._check_args(h), self.control.air,
                self.fg, self.volume, st.xv, self.status])


class RK4Solver(Solver):
    """Classical explicit fourth-order Runge-Kutta (the paper's reference integrator)."""

    name = "rk4"
    order = 4
    stability_constant = 2.5  # RK4 reaches |lambda h| ~ 2.8 on both axes

    def __init__(self, model: Model, state: State, control: Control, paper_bending: bool = False):
        super().__init__(model, state, control, paper_bending)
        shape, dev, vec3 = state.xv.shape, model.device, model.vec3
        self.stage_xv = wp.zeros(shape, dtype=vec3, device=dev)  # (2, W, V) the next stage point
        self.xs, self.vs = self.stage_xv[0], self.stage_xv[1]
        self.acc = wp.zeros(shape, dtype=vec3, device=dev)  # (2, W, V) weighted slope sums

    def step(self, h: float, launch: Launch):
        st, m = self.state, self.model
        W, V = st.x.shape
        hs = m.scalar(h)
        self.begin(launch)
        for stage in range(4):
            if stage == 0:
                self.forces(st.xv, st.x, st.v, stage, launch)
            else:
                self.forces(self.stage_xv, self.xs, self.vs, stage, launch)
            launch(ki.rk4_stage_fused, (W * V,),
                   [m.inv_mass, m.scalar(m.viscous_damping), *self._pressure_args(), hs, stage, W, V,
                    *self._check_args(h), self.control.air, self.volume, self.fg, st.xv, self.stage_xv, self.acc,
                    self.status])


INTEGRATORS = {"rk4": RK4Solver, "semi_implicit": SemiImplicitSolver}


def make_solver(integrator: str, model: Model, state: State, control: Control, paper_bending: bool = False) -> Solver:
    """The solver for an integrator name ('rk4', 'semi_implicit' and aliases); unknown names raise."""
    key = integrator.lower().replace("-", "_")
    if key in ("euler", "semi_implicit_euler", "symplectic_euler"):
        key = "semi_implicit"
    if key not in INTEGRATORS:
        raise DesignError(f"unknown integrator {integrator!r}; choose one of {sorted(INTEGRATORS)}")
    return INTEGRATORS[key](model, state, control, paper_bending)


# --------------------------------------------------------------------------- stable step

def _pair_rows(rows, a, b, k, inv_m, inv_sqrt):
    """Gershgorin rows of M^-1/2 K M^-1/2 for 2-point springs k between a and b (W, n)."""
    W = k.shape[0]
    for w in range(W):
        np.add.at(rows[w], a, k[w] * (inv_m[a] + inv_sqrt[a] * inv_sqrt[b]))
        np.add.at(rows[w], b, k[w] * (inv_m[b] + inv_sqrt[a] * inv_sqrt[b]))


def hinge_gradient_norms(x: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """(E, 4) norms of d(theta)/dx for each hinge vertex, at positions x (V, 3)."""
    x0, x1, x2, x3 = (x[hinges[:, k]] for k in range(4))
    e = x1 - x0
    len_e = np.linalg.norm(e, axis=1)
    h2 = np.linalg.norm(np.cross(e, x2 - x0), axis=1) / len_e
    h3 = np.linalg.norm(np.cross(x0 - x1, x3 - x1), axis=1) / len_e
    g2, g3 = 1.0 / h2, 1.0 / h3
    t2 = np.einsum("ij,ij->i", x2 - x0, e) / len_e**2
    t3 = np.einsum("ij,ij->i", x3 - x0, e) / len_e**2
    g1 = np.abs(t2) * g2 + np.abs(t3) * g3
    g0 = np.abs(1 - t2) * g2 + np.abs(1 - t3) * g3
    return np.stack([g0, g1, g2, g3], axis=1)


class _ElasticOperator:
    """y = M^-1/2 K M^-1/2 u for the elastic stiffness K of one world at positions x: edge springs
    (axial k d d^T plus the tension's transverse |k (1 - L_0/L)| (I - d d^T)), hinges (Gauss-Newton
    k_t g g^T with g = d(theta)/dx) and IPAM sub-springs (axial plus transverse). K is symmetric
    positive semi-definite, so Lanczos on it bounds its largest eigenvalue. Vectors are (3, V)
    structure-of-arrays, flattened."""

    def __init__(self, model: Model, x: np.ndarray, k_edge: np.ndarray, rest_len: np.ndarray, kt: np.ndarray | None):
        h = model.host
        self.V = model.n_vertices
        self.inv_sqrt = 1.0 / np.sqrt(h.mass)
        hinges = h.hinges
        xT = np.ascontiguousarray(x.T)
        a, b = [hinges[:, 0]], [hinges[:, 1]]
        d = xT[:, hinges[:, 1]] - xT[:, hinges[:, 0]]
        length = np.maximum(np.sqrt((d * d).sum(axis=0)), 1e-300)
        k_ax, k_tr, dirs = [k_edge], [np.abs(k_edge * (1.0 - rest_len / length))], [d / length]
        if model.has_ipams:
            pairs = h.ipam_sub_pairs
            dp = xT[:, pairs[:, 1]] - xT[:, pairs[:, 0]]
            lp = np.maximum(np.sqrt((dp * dp).sum(axis=0)), 1e-300)
            k_sub = np.repeat(h.ipam_stiffness / 3.0, 3)
            a.append(pairs[:, 0])
            b.append(pairs[:, 1])
            k_ax.append(k_sub)
            k_tr.append(k_sub)  # transverse k |1 - L_n/L| <= k while 0 <= L_n <= 2 L (as the Gershgorin bound)
            dirs.append(dp / lp)
        self.a, self.b = np.concatenate(a), np.concatenate(b)
        self.dir = np.concatenate(dirs, axis=1)
        k_ax, self.k_tr = np.concatenate(k_ax), np.concatenate(k_tr)
        self.k_diff = k_ax - self.k_tr
        self.idx2 = np.concatenate([self.a, self.b])
        self.grad = None
        if kt is not None:
            x0, x1, x2, x3 = (xT[:, hinges[:, c]] for c in range(4))
            e = x1 - x0
            ee = np.maximum((e * e).sum(axis=0), 1e-300)
            le = np.sqrt(ee)
            n_a = np.cross(e, x2 - x0, axis=0)
            n_b = np.cross(x0 - x1, x3 - x1, axis=0)
            g2 = -n_a * (le / np.maximum((n_a * n_a).sum(axis=0), 1e-300))
            g3 = -n_b * (le / np.maximum((n_b * n_b).sum(axis=0), 1e-300))
            t2 = ((x2 - x0) * e).sum(axis=0) / ee
            t3 = ((x3 - x0) * e).sum(axis=0) / ee
            g1 = -(g2 * t2 + g3 * t3)
            g0 = -(g2 * (1.0 - t2) + g3 * (1.0 - t3))
            self.hinges = [hinges[:, c] for c in range(4)]
            self.kt = kt
            self.grad = [g0, g1, g2, g3]  # 4 x (3, E)
            self.idx4 = np.concatenate(self.hinges)

    def _scatter(self, idx, vals):
        return np.stack([np.bincount(idx, weights=vals[c], minlength=self.V) for c in range(3)])

    @staticmethod
    def _dot3(a, b):
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    def __call__(self, u: np.ndarray) -> np.ndarray:
        u = u.reshape(3, -1) * self.inv_sqrt
        du = u[:, self.b] - u[:, self.a]
        ax = self._dot3(du, self.dir)
        kb = self.dir * (self.k_diff * ax) + du * self.k_tr  # (K u) on b; a takes -kb
        out = self._scatter(self.idx2, np.concatenate([-kb, kb], axis=1))
        if self.grad is not None:
            s = sum(self._dot3(g, u[:, hc]) for g, hc in zip(self.grad, self.hinges)) * self.kt
            out += self._scatter(self.idx4, np.concatenate([g * s for g in self.grad], axis=1))
        return (out * self.inv_sqrt).reshape(-1)


def lanczos_upper_bound(op, n: int, steps: int = 12, seed: int = 0) -> float:
    """Upper estimate of the largest eigenvalue of a symmetric PSD operator: the largest Ritz value of
    ``steps`` plain Lanczos steps plus the last off-diagonal beta (the bound estimator of Zhou and
    Saad, 2006). For the spring networks here it is a few percent above the largest eigenvalue (a
    lower-bound Ritz value plus the residual), where Gershgorin is 2-3x above it."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal(n)
    q /= math.sqrt(float(np.sum(q * q)))  # plain reductions: no BLAS threads for these short vectors
    q_prev = np.zeros(n)
    alpha, beta = [], []
    b = 0.0
    for _ in range(steps):
        w = op(q)
        a = float(np.sum(q * w))
        w -= a * q + b * q_prev
        alpha.append(a)
        b = math.sqrt(float(np.sum(w * w)))
        beta.append(b)
        if b <= 1e-14 * max(abs(a), 1e-300):
            break
        q_prev, q = q, w / b
    k = len(alpha)
    T = np.diag(alpha) + np.diag(beta[: k - 1], 1) + np.diag(beta[: k - 1], -1)
    return float(np.linalg.eigvalsh(T).max() + beta[k - 1])


#: Lanczos bound safety factor on omega^2. Over meshes of 162-10242 vertices, jammed or not, the
#: 12-step bound was 0.95-1.04 of a 100-step one and, where a dense eigensolve is affordable (162
#: vertices), 1.21-1.24 of the true largest eigenvalue; 1.2 covers the shortfall with margin.
LANCZOS_SAFETY = 1.2
LANCZOS_STEPS = 12


def elastic_omega2_bound(model: Model, edge_jammed: np.ndarray, x: np.ndarray,
                         rest_length: np.ndarray | None = None, steps: int = LANCZOS_STEPS) -> np.ndarray:
    """(W,) bound on the largest eigenvalue of M^-1/2 K M^-1/2 for the elastic stiffness (springs,
    hinges, IPAMs): LANCZOS_SAFETY x a short Lanczos bound. Depends on the jam state and, mildly, on
    positions (directions, tension); the Simulator caches it between jams, position sets and periodic
    re-estimates, and stable_dt_estimate caps it by the Gershgorin bound."""
    h = model.host
    W = x.shape[0]
    E = h.hinges.shape[0]
    rest = np.broadcast_to(h.rest_length, (W, E)) if rest_length is None else rest_length
    k_edge = h.edge_stiffness[None, :] * np.where(edge_jammed, model.jam_stretch_factor, 1.0)
    kt = model.bending_stiffness * np.where(edge_jammed, model.jam_bend_factor, 1.0) if model.has_bending else None
    out = np.zeros(W)
    for w in range(W):
        op = _ElasticOperator(model, x[w], k_edge[w], rest[w], None if kt is None else kt[w])
        out[w] = LANCZOS_SAFETY * lanczos_upper_bound(op, 3 * model.n_vertices, steps)
    return out


def stable_dt_estimate(model: Model, solver_cls, edge_jammed: np.ndarray, air: np.ndarray, x: np.ndarray,
                       rest_length: np.ndarray | None = None, refine: bool = True,
                       elastic_bound: np.ndarray | None = None) -> np.ndarray:
    """Conservative stable internal step per world (s).

    The highest undamped frequency omega is bounded by Gershgorin row sums of M^-1/2 K M^-1/2
    (edge, hinge and IPAM springs at their jammed stiffness, pressure's geometric stiffness), plus the
    rank-one gas compressibility term; with ``refine`` the elastic part (springs, hinges, IPAMs) is
    instead bounded by ``elastic_omega2_bound`` (a short Lanczos run with a safety factor; pass
    ``elastic_bound`` (W,) to reuse one), never above its Gershgorin bound, and the pressure terms
    are added to it (Weyl: lambda_max(A + B) <= lambda_max(A) + lambda_max(B)). The fastest damping
    rate gamma is bounded by Gershgorin. Returns stability_constant / (omega + gamma). edge_jammed: (W, E) bool;
    air: (W,) mol; x: (W, V, 3) positions; rest_length: (W, E) current spring rest lengths.
    """
    h = model.host
    W = x.shape[0]
    m = h.mass
    inv_m = 1.0 / m
    inv_sqrt = np.sqrt(inv_m)
    hinges = h.hinges
    a, b = hinges[:, 0], hinges[:, 1]
    V = model.n_vertices
    stiff = np.zeros((W, V))
    damp = np.zeros((W, V))
    k_edge = h.edge_stiffness[None, :] * np.where(edge_jammed, model.jam_stretch_factor, 1.0)
    _pair_rows(stiff, a, b, k_edge, inv_m, inv_sqrt)
    _pair_rows(damp, a, b, np.full((W, a.size), model.spring_damping), inv_m, inv_sqrt)
    damp += model.viscous_damping * inv_m[None, :]
    kt = None
    if model.has_bending:
        g = hinge_gradient_norms(h.rest_vertices, hinges)  # rest geometry: frozen per model
        kt = model.bending_stiffness * np.where(edge_jammed, model.jam_bend_factor, 1.0)  # (W, E)
        gs = g * inv_sqrt[hinges]  # |g_a| / sqrt(m_a)
        total = gs.sum(axis=1)
        for w in range(W):
            for c in range(4):
                np.add.at(stiff[w], hinges[:, c], kt[w] * gs[:, c] * total)
    if model.has_ipams:
        pairs = h.ipam_sub_pairs
        k_sub = np.repeat(h.ipam_stiffness / 3.0, 3)
        c_sub = np.repeat(h.ipam_damping, 3)
        _pair_rows(stiff, pairs[:, 0], pairs[:, 1], np.broadcast_to(k_sub, (W, k_sub.size)), inv_m, inv_sqrt)
        _pair_rows(damp, pairs[:, 0], pairs[:, 1], np.broadcast_to(c_sub, (W, c_sub.size)), inv_m, inv_sqrt)
    faces = h.faces
    gas_eig = np.zeros(W)
    press = np.zeros((W, V))
    volumes = np.maximum(volumes_np(x, faces), 1e-300)
    for w in range(W):
        xf = x[w][faces]
        n2a = np.cross(xf[:, 1] - xf[:, 0], xf[:, 2] - xf[:, 0])
        vol = float(volumes[w])
        p_abs = air[w] * model.gas_rt / vol
        p_gauge = abs(p_abs - model.atmospheric_pressure)
        perim = sum(np.linalg.norm(xf[:, (k + 1) % 3] - xf[:, k], axis=1) for k in range(3))
        np.add.at(press[w], faces.reshape(-1), np.repeat(p_gauge * perim / 6.0, 3) * inv_m[faces.reshape(-1)])
        grad_v = np.zeros((V, 3))
        np.add.at(grad_v, faces.reshape(-1), np.repeat(n2a / 6.0, 3, axis=0))
        gas_eig[w] = p_abs / vol * float(np.sum(np.einsum("ij,ij->i", grad_v, grad_v) * inv_m))
    omega2 = (stiff + press).max(axis=1) + gas_eig  # Gershgorin bound
    if refine:
        if elastic_bound is None:
            elastic_bound = elastic_omega2_bound(model, edge_jammed, x, rest_length)
        elastic = np.minimum(elastic_bound, stiff.max(axis=1))
        omega2 = np.minimum(omega2, elastic + press.max(axis=1) + gas_eig)
    omega = np.sqrt(omega2)
    gamma = damp.max(axis=1)
    return solver_cls.stability_constant / (omega + gamma)


def substeps_for(dt: float, dt_stable: float) -> int:
    """Fewest equal internal steps of an output step ``dt`` (s) within ``dt_stable`` (s)."""
    return max(1, int(math.ceil(dt / dt_stable - 1e-9)))
