"""Model-based refinement of the controls: bounded damped Gauss-Newton on the fit objective's residual.

The controls of a world are its air amount and its active IPAMs' pressures (passive IPAMs are held
neutral and left out). Scaled: air / rest air, pressure / 100 kPa. An iteration is at most two
batches of worlds (``Explorer``), each world started from the current state of its target:
1. the settled shape's finite-difference Jacobian: the current controls and one perturbed control per
   world (air by ``AIR_STEP`` of the rest air, a pressure by ``PRESSURE_STEP``, away from its limit);
   the residual is sqrt(w / sum w) (R - r) / V_t^(1/3) at the vertices, so that its norm is the fit
   objective (``objectives.radial.fit_objective``). After a full accepted step the Jacobian is carried on by
   Broyden's rank-one update instead, and this batch is skipped; it is rebuilt after a shorter step
   or when a Broyden-updated step fails;
2. the bounded damped Gauss-Newton step (Levenberg-Marquardt damping, pressure limits, a trust box of
   ``AIR_TRUST`` and ``PRESSURE_TRUST`` per iteration) tried at the step lengths ``STEP_LENGTHS``.
The best step length is kept when it lowers the objective; a world stops when the best lowers it by
less than the relative ``tolerance`` (still kept), when none lowers it with a fresh Jacobian, or at
the iteration limit.

A world with many controls takes its gradient from the equilibrium's adjoint instead
(``gradient="adjoint"``, or ``"auto"`` from ``ADJOINT_FROM`` active controls on;
``gradients.equilibrium``): one linear solve at its settled state, whatever the number of controls,
and a quasi-Newton (BFGS) model of the objective's Hessian in place of J^T J; its step is the same
bounded solve within the same boxes, tried at the same step lengths in the same batch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..gradients.equilibrium import EquilibriumGradient
from ..objectives.radial import SCALED_RADIAL, fit_objective_and_gradient
from .explore import Explorer
from .gauss_newton import bounded_step
from .control_settings import GRADIENTS

__all__ = ["Refined", "refine", "AIR_STEP", "PRESSURE_STEP", "PRESSURE_SCALE", "STEP_LENGTHS", "GRADIENTS",
           "ADJOINT_FROM"]

PRESSURE_SCALE = 1.0e5  # Pa per unit of a scaled pressure control
AIR_STEP = 0.01  # finite-difference step of the air, fraction of the rest air
PRESSURE_STEP = 1.0e4  # finite-difference step of a pressure, Pa
AIR_TRUST = 0.15  # largest air change per iteration, fraction of the rest air
PRESSURE_TRUST = 1.0e5  # largest pressure change per iteration, Pa
STEP_LENGTHS = (1.0, 0.5, 0.25)  # fractions of the Gauss-Newton step tried in one batch
DAMPING = 1e-3  # initial Levenberg-Marquardt damping, relative to the mean diagonal of J^T J
ADJOINT_FROM = 32  # "auto": the adjoint from this many active controls on (docs/gradients.md: beyond the measured range)
ADJOINT_TOLERANCE = 1e-4  # relative residual of the adjoint's linear solve
ADJOINT_SHRINKS = 2  # times a fresh quasi-Newton model's step is cut 8x before the world stops

STOP_TOLERANCE = "the objective improved by less than the tolerance"
STOP_NO_STEP = "no step lowered the objective"
STOP_LIMIT = "iteration limit reached"
STOP_NOTHING = "no refinement asked (inverse_iterations = 0)"
STOP_ADJOINT = "the equilibrium's adjoint solve failed (not a stable equilibrium)"


@dataclass
class Refined:
    """The refined controls of every world and how the refinement went."""

    air: np.ndarray  # (W,) mol
    pressures: np.ndarray  # (W, n_ipam) Pa
    start_objective: np.ndarray  # (W,) objective of the starting controls, settled
    objective: np.ndarray  # (W,) objective of the refined controls, settled in the scratch batch
    start_mare: np.ndarray  # (W,) MARE of the starting controls, settled, m
    mare: np.ndarray  # (W,) MARE of the refined controls, settled, m
    iterations: np.ndarray  # (W,) Gauss-Newton steps taken
    stop: list  # (W,) what stopped each world (one of the STOP_* texts)
    saturated: list  # (W,) per world: actuators at a limit whose gradient asks for more
    trace: list = field(default_factory=list)  # (W,) objective after each iteration


class _World:
    """One target's refinement state (scaled controls u, bounds, damping, its current world state)."""

    def __init__(self, w, state, air, pressures, active, host):
        self.w, self.state, self.host = w, state, host
        self.rest_air = host.rest_air
        self.u = np.concatenate([[air / host.rest_air], np.asarray(pressures) / PRESSURE_SCALE])
        self.active = np.concatenate([[True], active])  # air always; IPAMs unless passive
        lim = host.ipam_limits / PRESSURE_SCALE
        self.lo = np.concatenate([[0.0], lim[:, 0]])
        self.hi = np.concatenate([[np.inf], lim[:, 1]])
        self.trust = np.concatenate([[AIR_TRUST], np.full(host.n_ipams, PRESSURE_TRUST / PRESSURE_SCALE)])
        self.mu, self.objective, self.start, self.iterations = DAMPING, None, None, 0
        self.mare, self.start_mare = np.nan, np.nan
        self.stop, self.running, self.trace, self.J, self.e = STOP_LIMIT, True, [], None, None
        self.fresh = False  # J is a finite-difference Jacobian at the current controls (not a Broyden update)
        self.stale = True  # J must be rebuilt by finite differences before the next step
        self.weights = None
        self.adjoint = False  # True: the gradient g from the equilibrium's adjoint, B its BFGS Hessian model
        self.g, self.B, self.shrinks = None, None, 0
        self.mu_adjoint = None  # the last adjoint solve's solution (the next one starts from it)

    def controls(self, u) -> tuple[float, np.ndarray]:
        return float(u[0] * self.rest_air), np.clip(u[1:], self.lo[1:], self.hi[1:]) * PRESSURE_SCALE

    def perturbations(self) -> list[tuple[int, float]]:
        """(control index, scaled step) of every active control, stepping away from a near limit (none
        where the gradient comes from the adjoint)."""
        out = []
        if self.adjoint:
            return out
        for k in np.flatnonzero(self.active):
            h = AIR_STEP if k == 0 else PRESSURE_STEP / PRESSURE_SCALE
            out.append((int(k), h if self.u[k] + h <= self.hi[k] else -h))
        return out

    def step(self) -> np.ndarray:
        """The bounded damped Gauss-Newton step (scaled, zero on passive controls); with the adjoint's
        gradient g and the BFGS model B, the bounded minimiser of g.d + d.B.d / 2 (the same solve:
        |e + R d|^2 with B = R^T R, R^T e = g)."""
        a = self.active
        lo = np.maximum(self.lo - self.u, -self.trust)[a]
        hi = np.minimum(self.hi - self.u, self.trust)[a]
        d = np.zeros_like(self.u)
        if self.adjoint:
            R = np.linalg.cholesky(self.B).T
            e = np.linalg.solve(R.T, self.g[a])
            lam = 1e-12 * float(np.mean(np.diag(self.B)))
            d[a] = bounded_step(R, e, lam, np.minimum(lo, 0.0), np.maximum(hi, 0.0))
            return d
        J, e = self.J, self.e
        lam = self.mu * max(float(np.mean(np.sum(J[:, a] ** 2, axis=0))), 1e-30)
        d[a] = bounded_step(J[:, a], e, lam, np.minimum(lo, 0.0), np.maximum(hi, 0.0))
        return d

    def reset_model(self) -> None:
        """B: the scaled identity whose unconstrained step just reaches the trust box."""
        a = self.active
        b = float(np.max(np.abs(self.g[a]) / self.trust[a]))
        self.B = np.eye(int(a.sum())) * max(b, 1e-30)
        self.fresh, self.shrinks = True, 0

    def saturated(self) -> list[str]:
        """Active IPAMs at a pressure limit whose objective gradient points past it."""
        if self.adjoint:
            if self.g is None:
                return []
            g = self.g
        elif self.J is None:
            return []
        else:
            g = self.J.T @ self.e
        out = []
        for i in range(self.host.n_ipams):
            k = i + 1
            if not self.active[k]:
                continue
            if self.u[k] >= self.hi[k] - 1e-9 and g[k] < 0:
                out.append(f"ipam {i} at P_max {self.hi[k] * PRESSURE_SCALE / 1e3:g} kPa")
            elif self.u[k] <= self.lo[k] + 1e-9 and g[k] > 0:
                out.append(f"ipam {i} at P_min {self.lo[k] * PRESSURE_SCALE / 1e3:g} kPa")
        return out


def _jacobians(explorer: Explorer, worlds: list[_World], targets: np.ndarray) -> None:
    """One batch: every running world's current controls and one perturbation per active control;
    sets each world's residual ``e``, Jacobian ``J`` and settled ``objective`` (and its start)."""
    states, air, press, tg, index = [], [], [], [], []
    for wd in worlds:
        pert = wd.perturbations()
        for k, h in [(None, 0.0)] + pert:
            u = wd.u.copy()
            if k is not None:
                u[k] += h
            a, p = wd.controls(u)
            states.append(wd.state)
            air.append(a)
            press.append(p)
            tg.append(targets[wd.w])
        index.append((len(states) - len(pert) - 1, pert))
    S = explorer.settle(states, np.array(air), np.array(press), np.array(tg))
    for wd, (b, pert) in zip(worlds, index):
        vol = explorer.target_volume[targets[wd.w]]
        wd.weights = S.weights[b]
        wd.e = SCALED_RADIAL.residuals(S.r[b], S.R[b], wd.weights, vol)
        wd.J = np.zeros((wd.e.size, wd.u.size))
        for n, (k, h) in enumerate(pert):
            wd.J[:, k] = (SCALED_RADIAL.residuals(S.r[b + 1 + n], S.R[b + 1 + n], wd.weights, vol) - wd.e) / h
        wd.objective, wd.fresh, wd.stale = float(S.objective[b]), True, False
        wd.state, wd.mare = S.states[b], float(S.mare[b])
        if wd.start is None:
            wd.start, wd.start_mare = wd.objective, wd.mare
        if wd.adjoint:
            wd.g = _adjoint_gradient(explorer, wd, targets[wd.w])
            if wd.g is None:
                wd.stop, wd.running = STOP_ADJOINT, False
            else:
                wd.reset_model()


def _adjoint_gradient(explorer: Explorer, wd: _World, target: int) -> np.ndarray | None:
    """dJ/du (scaled controls, zero on passive ones) at the world's settled state, by the equilibrium's
    adjoint; None where its solve fails."""
    if explorer.equilibrium_gradient is None:
        explorer.equilibrium_gradient = EquilibriumGradient(explorer.host, explorer.design.material, explorer.device)
    eg, ref, host = explorer.equilibrium_gradient, wd.state, explorer.host
    x = ref.state.xv.numpy()[0, ref.world].astype(np.float64)
    edge = ref.state.edge.numpy()[:, ref.world].astype(np.float64)
    air, p = wd.controls(wd.u)
    _, dj_dx = fit_objective_and_gradient(x, explorer.sampler, int(target), host.faces,
                                          float(explorer.target_volume[target]))
    jam = {k: {n: a.numpy()[..., ref.world:ref.world + 1, :] for n, a in f.items()} for k, f in ref.state.family_jam.items()}
    eg.load(x, edge, air, p, ~explorer.passive[target] if host.n_ipams else None, family_jam=jam)
    cg = eg.control_gradient(dj_dx, tolerance=ADJOINT_TOLERANCE, guess=wd.mu_adjoint)
    explorer.adjoint_iterations += cg.iterations
    if not cg.converged:
        return None
    wd.mu_adjoint = cg.adjoint
    g = np.concatenate([[cg.air * wd.rest_air], cg.pressures * PRESSURE_SCALE])
    return np.where(wd.active, g, 0.0)


def _accept(wd: _World, d: np.ndarray, alpha: float, e_new: np.ndarray, objective: float, state,
            target: int) -> None:
    """Take the step ``alpha d``; after a full step the Jacobian is carried on by Broyden's update
    (the next iteration needs no finite-difference batch), after a shorter one it is rebuilt. A world
    on the adjoint takes the gradient at the new point and updates its BFGS model."""
    du = alpha * d
    if wd.adjoint:
        pass
    elif alpha == STEP_LENGTHS[0]:
        wd.J = wd.J + np.outer(e_new - wd.e - wd.J @ du, du) / float(du @ du)
        wd.e, wd.fresh = e_new, False
        wd.mu *= 0.3
    else:
        wd.fresh, wd.stale = False, True
        wd.mu *= 3.0
    u_old = wd.u
    wd.u = wd.u + du
    wd.u[1:] = np.clip(wd.u[1:], wd.lo[1:], wd.hi[1:])
    wd.state, wd.objective = state, objective
    wd.iterations += 1
    wd.trace.append(objective)
    if wd.adjoint:
        _bfgs_update(wd, wd.u - u_old, target)


def _bfgs_update(wd: _World, s_full: np.ndarray, target: int) -> None:
    """The adjoint's gradient at the accepted point and the BFGS update of B by the step s and the
    gradient change y (skipped where s.y is not positive)."""
    g_old = wd.g
    g = _adjoint_gradient(wd.explorer, wd, target)
    if g is None:
        wd.stop, wd.running = STOP_ADJOINT, False
        return
    wd.g = g
    a = wd.active
    s, y = s_full[a], (g - g_old)[a]
    sy = float(s @ y)
    if sy > 1e-12 * float(np.linalg.norm(s) * np.linalg.norm(y)):
        Bs = wd.B @ s
        wd.B = wd.B + np.outer(y, y) / sy - np.outer(Bs, Bs) / float(s @ Bs)
    wd.fresh = False


def _line_search(explorer: Explorer, worlds: list[_World], targets: np.ndarray, tolerance: float) -> None:
    """One batch: every running world's step at every step length; keep the best, or stop."""
    states, air, press, tg, steps = [], [], [], [], []
    for wd in worlds:
        d = wd.step()
        steps.append(d)
        for alpha in STEP_LENGTHS:
            a, p = wd.controls(wd.u + alpha * d)
            states.append(wd.state)
            air.append(a)
            press.append(p)
            tg.append(targets[wd.w])
    S = explorer.settle(states, np.array(air), np.array(press), np.array(tg))
    L = len(STEP_LENGTHS)
    for n, (wd, d) in enumerate(zip(worlds, steps)):
        obj = S.objective[n * L:(n + 1) * L]
        best = int(np.argmin(obj))
        if not np.any(d) or obj[best] >= wd.objective:
            if wd.adjoint and wd.fresh and wd.shrinks < ADJOINT_SHRINKS:  # the model's first step: 8x shorter
                wd.B, wd.shrinks = wd.B * 8.0, wd.shrinks + 1
            elif wd.fresh:
                wd.stop, wd.running = STOP_NO_STEP, False
            elif wd.adjoint:  # a BFGS model failed: restart it from the scaled identity
                wd.reset_model()
            else:  # a Broyden-updated Jacobian failed: rebuild it before giving up
                wd.stale = True
            continue
        gain = (wd.objective - obj[best]) / wd.objective
        i = n * L + best
        e_new = SCALED_RADIAL.residuals(S.r[i], S.R[i], wd.weights, explorer.target_volume[targets[wd.w]])
        wd.mare = float(S.mare[i])
        _accept(wd, d, STEP_LENGTHS[best], e_new, float(obj[best]), S.states[i], targets[wd.w])
        if gain < tolerance and wd.running:
            wd.stop, wd.running = STOP_TOLERANCE, False


def uses_adjoint(gradient: str, controls: int, settle: str) -> bool:
    """Whether a world with ``controls`` active controls takes the adjoint's gradient: asked for, or
    ``"auto"`` from ``ADJOINT_FROM`` controls on; never with dynamic scratch settles (no equilibrium)."""
    if gradient not in GRADIENTS:
        raise ValueError(f"gradient must be one of {GRADIENTS}, got {gradient!r}")
    if settle != "static":
        return False
    return gradient == "adjoint" or (gradient == "auto" and controls >= ADJOINT_FROM)


def refine(explorer: Explorer, states: list, air: np.ndarray, pressures: np.ndarray, targets: np.ndarray,
           active: np.ndarray, iterations: int, tolerance: float, gradient: str = "finite-difference") -> Refined:
    """Refine every world's controls from its ``states`` entry (W,) and its controls ``air`` (W,),
    ``pressures`` (W, n_ipam); world w fits target ``targets[w]`` and refines the IPAMs ``active[w]``.
    ``gradient``: one of ``GRADIENTS`` (``uses_adjoint``)."""
    host = explorer.host
    worlds = [_World(w, states[w], air[w], pressures[w], active[w], host) for w in range(len(states))]
    for wd in worlds:
        wd.explorer = explorer
        wd.adjoint = uses_adjoint(gradient, int(wd.active.sum()), explorer.sim_settings.settle)
    for it in range(iterations):
        running = [wd for wd in worlds if wd.running]
        if not running:
            break
        stale = [wd for wd in running if wd.stale]
        if stale:
            _jacobians(explorer, stale, targets)
        _line_search(explorer, running, targets, tolerance)
    if iterations == 0:
        for wd in worlds:
            wd.stop = STOP_NOTHING
    out_air, out_p = zip(*[wd.controls(wd.u) for wd in worlds]) if worlds else ((), ())
    nan = float("nan")
    return Refined(air=np.array(out_air), pressures=np.array(out_p).reshape(len(worlds), host.n_ipams),
                   start_objective=np.array([wd.start if wd.start is not None else nan for wd in worlds]),
                   objective=np.array([wd.objective if wd.objective is not None else nan for wd in worlds]),
                   start_mare=np.array([wd.start_mare for wd in worlds]), mare=np.array([wd.mare for wd in worlds]),
                   iterations=np.array([wd.iterations for wd in worlds]), stop=[wd.stop for wd in worlds],
                   saturated=[wd.saturated() for wd in worlds], trace=[wd.trace for wd in worlds])
