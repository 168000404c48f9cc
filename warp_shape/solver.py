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

from warp_shape.kernels import integrate as ki
from warp_shape.kernels import membrane as km

from .errors import DesignError
from .model import Control, Model, State

__all__ = ["FORCE_TERMS", "eval_forces", "Solver", "RK4Solver", "SemiImplicitSolver", "make_solver",
           "stable_dt_estimate", "INTEGRATORS"]

Launch = Callable[[wp.Kernel, tuple, list], None]

FORCE_TERMS = ("spring", "bending", "pressure", "ipam", "viscous")


# --------------------------------------------------------------------------- force families

def eval_init_viscous(model: Model, v, f, volume, launch: Launch, enabled: bool = True):
    c_v = model.viscous_damping if enabled else 0.0
    launch(km.init_forces_viscous, f.shape, [model.scalar(c_v), v, f, volume])


def eval_volume(model: Model, x, volume, launch: Launch):
    launch(km.eval_volume_kernel, (x.shape[0], model.n_faces), [model.faces, x, volume])


def eval_pressure(model: Model, x, volume, control: Control, f, launch: Launch):
    launch(km.eval_pressure_kernel, (x.shape[0], model.n_faces),
           [model.faces, wp.float64(model.gas_rt), wp.float64(model.atmospheric_pressure), x, volume,
            control.air, f])


def eval_springs(model: Model, state: State, x, v, f, launch: Launch):
    s = model.scalar
    launch(km.eval_spring_kernel, (x.shape[0], model.n_edges),
           [model.hinges, model.edge_stiffness, s(model.spring_damping), s(model.jam_stretch_factor), x, v,
            state.rest_length, state.jammed, f])


def eval_bending(model: Model, state: State, x, f, launch: Launch, paper: bool = False):
    if not model.has_bending:
        return
    s = model.scalar
    launch(km.eval_bending_kernel, (x.shape[0], model.n_edges),
           [model.hinges, s(model.bending_stiffness), s(model.jam_bend_factor), int(paper), x,
            state.rest_angle, state.jammed, f])


def eval_ipams(model: Model, x, v, control: Control, f, launch: Launch):
    if not model.has_ipams:
        return
    launch(km.eval_ipam_kernel, (x.shape[0], 3 * model.n_ipams),
           [model.ipam_sub_pairs, model.ipam_sub_offsets, model.ipam_stiffness, model.ipam_area_over_k,
            model.ipam_free_length, model.ipam_damping, x, v, control.ipam_pressure, f])


def eval_forces(model: Model, state: State, control: Control, x, v, f, volume, launch: Launch,
                paper_bending: bool = False, terms=FORCE_TERMS):
    """Total force at (x, v) into f (overwritten); volume receives the enclosed volume per world."""
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
        self.f = wp.zeros((W, V), dtype=model.vec3, device=model.device)
        self.volume = wp.zeros(W, dtype=wp.float64, device=model.device)

    def forces(self, x, v, launch: Launch):
        eval_forces(self.model, self.state, self.control, x, v, self.f, self.volume, launch, self.paper_bending)

    def step(self, h: float, launch: Launch):  # pragma: no cover - abstract
        raise NotImplementedError


class SemiImplicitSolver(Solver):
    """Symplectic Euler: first order, one force evaluation per step."""

    name = "semi_implicit"
    order = 1
    stability_constant = 1.9  # omega h < 2 for the undamped oscillator

    def step(self, h: float, launch: Launch):
        st = self.state
        self.forces(st.x, st.v, launch)
        launch(ki.integrate_semi_implicit, st.x.shape, [self.model.inv_mass, self.model.scalar(h), self.f, st.x, st.v])


class RK4Solver(Solver):
    """Classical explicit fourth-order Runge-Kutta (the paper's reference integrator)."""

    name = "rk4"
    order = 4
    stability_constant = 2.5  # RK4 reaches |lambda h| ~ 2.8 on both axes

    def __init__(self, model: Model, state: State, control: Control, paper_bending: bool = False):
        super().__init__(model, state, control, paper_bending)
        shape, dev, vec3 = state.x.shape, model.device, model.vec3
        self.xs = wp.zeros(shape, dtype=vec3, device=dev)
        self.vs = wp.zeros(shape, dtype=vec3, device=dev)
        self.acc_x = wp.zeros(shape, dtype=vec3, device=dev)
        self.acc_v = wp.zeros(shape, dtype=vec3, device=dev)

    def step(self, h: float, launch: Launch):
        st, m = self.state, self.model
        hs = m.scalar(h)
        for stage in range(4):
            x_eval, v_eval = (st.x, st.v) if stage == 0 else (self.xs, self.vs)
            self.forces(x_eval, v_eval, launch)
            launch(ki.rk4_stage, st.x.shape,
                   [m.inv_mass, hs, stage, self.f, v_eval, st.x, st.v, self.xs, self.vs, self.acc_x, self.acc_v])


INTEGRATORS = {"rk4": RK4Solver, "semi_implicit": SemiImplicitSolver}


def make_solver(integrator: str, model: Model, state: State, control: Control, paper_bending: bool = False) -> Solver:
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


def stable_dt_estimate(model: Model, solver_cls, edge_jammed: np.ndarray, air: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Conservative stable internal step per world (s).

    Bounds the highest undamped frequency omega by Gershgorin row sums of M^-1/2 K M^-1/2
    (edge, hinge and IPAM springs at their jammed stiffness, pressure's geometric stiffness, plus
    the rank-one gas compressibility term) and the fastest damping rate gamma the same way, then
    returns stability_constant / (omega + gamma). edge_jammed: (W, E) bool; air: (W,) mol;
    x: (W, V, 3) positions.
    """
    h = model.host
    W = x.shape[0]
    m = h["mass"]
    inv_m = 1.0 / m
    inv_sqrt = np.sqrt(inv_m)
    hinges = h["hinges"]
    a, b = hinges[:, 0], hinges[:, 1]
    V = model.n_vertices
    stiff = np.zeros((W, V))
    damp = np.zeros((W, V))
    k_edge = h["edge_stiffness"][None, :] * np.where(edge_jammed, model.jam_stretch_factor, 1.0)
    _pair_rows(stiff, a, b, k_edge, inv_m, inv_sqrt)
    _pair_rows(damp, a, b, np.full((W, a.size), model.spring_damping), inv_m, inv_sqrt)
    damp += model.viscous_damping * inv_m[None, :]
    if model.has_bending:
        g = hinge_gradient_norms(h["rest_vertices"], hinges)  # rest geometry: frozen per model
        kt = model.bending_stiffness * np.where(edge_jammed, model.jam_bend_factor, 1.0)  # (W, E)
        gs = g * inv_sqrt[hinges]  # |g_a| / sqrt(m_a)
        total = gs.sum(axis=1)
        for w in range(W):
            for c in range(4):
                np.add.at(stiff[w], hinges[:, c], kt[w] * gs[:, c] * total)
    if model.has_ipams:
        pairs = h["ipam_sub_pairs"]
        k_sub = np.repeat(h["ipam_stiffness"] / 3.0, 3)
        c_sub = np.repeat(h["ipam_damping"], 3)
        _pair_rows(stiff, pairs[:, 0], pairs[:, 1], np.broadcast_to(k_sub, (W, k_sub.size)), inv_m, inv_sqrt)
        _pair_rows(damp, pairs[:, 0], pairs[:, 1], np.broadcast_to(c_sub, (W, c_sub.size)), inv_m, inv_sqrt)
    faces = h["faces"]
    gas_eig = np.zeros(W)
    for w in range(W):
        xf = x[w][faces]
        n2a = np.cross(xf[:, 1] - xf[:, 0], xf[:, 2] - xf[:, 0])
        vol = float(np.einsum("ij,ij->i", xf[:, 0], np.cross(xf[:, 1], xf[:, 2])).sum() / 6.0)
        vol = max(vol, 1e-300)
        p_abs = air[w] * model.gas_rt / vol
        p_gauge = abs(p_abs - model.atmospheric_pressure)
        perim = sum(np.linalg.norm(xf[:, (k + 1) % 3] - xf[:, k], axis=1) for k in range(3))
        np.add.at(stiff[w], faces.reshape(-1), np.repeat(p_gauge * perim / 6.0, 3) * inv_m[faces.reshape(-1)])
        grad_v = np.zeros((V, 3))
        np.add.at(grad_v, faces.reshape(-1), np.repeat(n2a / 6.0, 3, axis=0))
        gas_eig[w] = p_abs / vol * float(np.sum(np.einsum("ij,ij->i", grad_v, grad_v) * inv_m))
    omega = np.sqrt(stiff.max(axis=1) + gas_eig)
    gamma = damp.max(axis=1)
    return solver_cls.stability_constant / (omega + gamma)


def substeps_for(dt: float, dt_stable: float) -> int:
    return max(1, int(math.ceil(dt / dt_stable - 1e-9)))
