"""Co-design after placement: the shared rest shape and the IPAM sizes descended by exact gradients.

Each target's final control sequence is replayed open loop on the design and differentiated
(``gradients.gradient``). The rest shape moves by smooth radial modes (each vertex scaled by
exp(sum_m c_m Y_m(u)), Y_m the polynomials of degree 1..``degree`` in the rest direction u,
orthonormal over the vertices), so it stays closed, star-shaped and smooth; the rest volume stays
within the initialisation's bound. IPAM areas and stiffnesses move in log scale within
``size_bounds`` x their placed values. A step follows the common descent direction of the targets
(the min-norm point of their gradients' convex hull), is shortened until no target's replayed
objective rises, and the design is re-controlled with the design's controller at the end; it is
kept only if no target's final objective is worse than before co-design. docs/gradients.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..controller import ControlSettings, control_many
from ..controller.replay import replay
from ..controller.shard import run_jobs
from ..design import Design
from ..gradients import gradient
from ..mesh import TriMesh
from ..objective_grad import fit_objective_and_gradient
from ..sampling import RadialSampler
from .settings import CODESIGN_MODES

__all__ = ["CODESIGN_MODES", "CodesignSettings", "CodesignProblem", "codesign", "radial_modes", "min_norm_direction",
           "replayed_objectives"]



@dataclass(frozen=True)
class CodesignSettings:
    """Co-design's parameters: ``steps`` descent steps, ``degree`` of the radial modes, the largest
    radial change per step ``max_radial_step`` (relative), the largest IPAM size change per step
    ``max_size_step`` (in log scale) and the IPAM size bounds ``size_bounds`` (x the placed value),
    ``halvings`` step shortenings tried before co-design stops."""

    steps: int = 4
    degree: int = 4
    max_radial_step: float = 0.03
    max_size_step: float = 0.3
    size_bounds: tuple = (0.5, 2.0)
    halvings: int = 3
    move_rest: bool = True  # False: the rest shape is the user's (single-target mode); only sizes move


@dataclass
class CodesignRecord:
    """What co-design did: the mode, each accepted step's replayed objectives, the objectives before
    and after (the design's controller), the rest shape's largest displacement (m), the IPAM sizes
    before and after, whether the co-designed design was kept and why."""

    mode: str
    steps: list = field(default_factory=list)
    before: list = field(default_factory=list)
    after: list = field(default_factory=list)
    max_displacement: float = 0.0
    ipam_area: tuple = ((), ())
    ipam_stiffness: tuple = ((), ())
    kept: bool = False
    reason: str = ""

    def as_dict(self) -> dict:
        return dict(mode=self.mode, steps=self.steps, before=self.before, after=self.after,
                    max_displacement_m=self.max_displacement, kept=self.kept, reason=self.reason,
                    ipam_area_m2=[list(map(float, a)) for a in self.ipam_area],
                    ipam_stiffness_n_per_m=[list(map(float, k)) for k in self.ipam_stiffness])


def radial_modes(rest: np.ndarray, degree: int) -> np.ndarray:
    """(M, V) smooth radial modes on the rest directions: the monomials of degree 1..``degree`` in
    u = x / |x|, orthonormalised over the vertices (dependent combinations dropped)."""
    u = rest / np.linalg.norm(rest, axis=1, keepdims=True)
    cols = []
    for total in range(1, degree + 1):
        for a in range(total + 1):
            for b in range(total - a + 1):
                c = total - a - b
                cols.append(u[:, 0] ** a * u[:, 1] ** b * u[:, 2] ** c)
    basis = np.stack(cols, axis=1)
    basis = basis - basis.mean(axis=0)  # a uniform scale is the volume bound's, not a mode
    q, sv, _ = np.linalg.svd(basis, full_matrices=False)
    return (q[:, sv > 1e-8 * sv[0]] * np.sqrt(len(rest))).T


def min_norm_direction(grads: np.ndarray, iterations: int = 200) -> np.ndarray:
    """The min-norm point of the convex hull of the rows of ``grads`` (T, P) (Frank-Wolfe): minus it
    is a direction along which no target's objective rises to first order (zero where none exists)."""
    T = len(grads)
    if T == 1:
        return grads[0].copy()
    G = grads @ grads.T
    w = np.full(T, 1.0 / T)
    for _ in range(iterations):
        t = int(np.argmin(G @ w))
        d = np.zeros(T)
        d[t] = 1.0
        diff = d - w
        denom = diff @ G @ diff
        if denom <= 0:
            break
        gamma = float(np.clip(-(w @ G @ diff) / denom, 0.0, 1.0))
        if gamma <= 1e-12:
            break
        w = w + gamma * diff
    return w @ grads


class CodesignProblem:
    """The parameterised design: rest modes c (M,) and IPAM log sizes (2 n,) -> a Design."""

    def __init__(self, design: Design, mode: str, settings: CodesignSettings, volume_bound: float):
        self.base, self.mode, self.settings, self.volume_bound = design, mode, settings, volume_bound
        self.x0 = design.rest.vertices.copy()
        self.modes = radial_modes(self.x0, settings.degree) if settings.move_rest else np.zeros((0, len(self.x0)))
        self.area0 = np.array([ip.area for ip in design.ipams])
        self.k0 = np.array([ip.stiffness for ip in design.ipams])
        self.sizes = mode == "rest+ipams" and design.n_ipams > 0
        self.n_sizes = 2 * design.n_ipams if self.sizes else 0

    @property
    def size(self) -> int:
        return len(self.modes) + self.n_sizes

    def design(self, p: np.ndarray) -> Design:
        M = len(self.modes)
        x = self.x0 * np.exp(p[:M] @ self.modes)[:, None] if M else self.x0
        rest = TriMesh(x, self.base.rest.faces)
        vol = rest.volume()
        if M and vol > self.volume_bound:
            rest = rest.scaled((self.volume_bound / vol) ** (1.0 / 3.0))
        n = self.base.n_ipams
        area = self.area0 * np.exp(p[M:M + n]) if self.sizes else self.area0
        k = self.k0 * np.exp(p[M + n:]) if self.sizes else self.k0
        out = Design(rest, self.base.material)
        for i, ip in enumerate(self.base.ipams):
            out.add_ipam(ip.face_a, ip.face_b, stiffness=float(k[i]), area=float(area[i]),
                         free_length=None if ip.free_length_is_rest else ip.free_length, pressure_limits=ip.pressure_limits,
                         damping=ip.damping)
        for c in self.base.cells:
            out.add_cell(c.faces)
        out.set_stretch_scale(self.base.stretch_scale)
        return out

    def chain(self, design: Design, values: dict) -> np.ndarray:
        """d objective / d parameters from the gradient's values on ``design``."""
        x = design.rest.vertices
        g_modes = self.modes @ np.einsum("vi,vi->v", values["rest_positions"], x)
        if not self.sizes:
            return g_modes
        area = np.array([ip.area for ip in design.ipams])
        k = np.array([ip.stiffness for ip in design.ipams])
        return np.concatenate([g_modes, values["ipam_area"] * area, values["ipam_stiffness"] * k])

    def gradients(self, design: Design, results, targets, device: str = "cpu") -> np.ndarray:
        """(T, P) d objective / d parameters of each target's sequence replayed on ``design`` (one job
        per target on the run's workers where they are running)."""
        wrt = ("rest_positions", "ipam_area", "ipam_stiffness")
        values = run_jobs(_gradient_job, [(design, r, t, wrt, device) for r, t in zip(results, targets)])
        return np.stack([self.chain(design, v) for v in values])

    def clip_step(self, p: np.ndarray, step: np.ndarray) -> np.ndarray:
        """``step`` scaled into the per-step limits, and p + step into the size bounds."""
        M, s = len(self.modes), self.settings
        radial = np.abs(step[:M] @ self.modes).max() if M else 0.0
        scale = min(1.0, s.max_radial_step / radial) if radial > 0 else 1.0
        if self.n_sizes:
            big = np.abs(step[M:]).max()
            scale = min(scale, s.max_size_step / big) if big > 0 else scale
        q = p + step * scale
        if self.n_sizes:
            lo, hi = np.log(s.size_bounds[0]), np.log(s.size_bounds[1])
            q[M:] = np.clip(q[M:], lo, hi)
        return q


def _gradient_job(design: Design, result, target, wrt, device: str, *, progress=None) -> dict:
    return gradient(design, result, target, wrt=wrt, device=device).values


def _objective_job(design: Design, result, target, device: str, *, progress=None) -> float:
    x = replay(design, result, device=device)
    sampler = RadialSampler(target, device=device)
    return float(fit_objective_and_gradient(x, sampler, 0, design.rest.faces, target.volume())[0])


def replayed_objectives(design: Design, results, targets, device: str = "cpu") -> np.ndarray:
    """(T,) the objective of each result's sequence replayed open loop on ``design`` (one job per
    target on the run's workers where they are running)."""
    return np.array(run_jobs(_objective_job, [(design, r, t, device) for r, t in zip(results, targets)]))


def codesign(design: Design, targets, results, *, mode: str = "rest+ipams", volume_bound: float,
             control_settings: ControlSettings, passive_ipams, passive_cells, device: str = "cpu",
             settings: CodesignSettings | None = None, target_names=None, progress=None):
    """Co-design ``design`` (placed; ``results``: its final control result per centred target) in
    ``mode`` (see ``CODESIGN_MODES``). Returns (design, results, CodesignRecord): the co-designed
    design re-controlled with ``control_settings`` where no target got worse, else the input ones."""
    settings = settings or CodesignSettings()
    record = CodesignRecord(mode=mode, before=[float(r.objective) for r in results])
    if mode == "off":
        record.reason = "co-design off"
        return design, results, record
    problem = CodesignProblem(design, mode, settings, volume_bound)
    if problem.size == 0:
        record.reason, record.after = "nothing to co-design (the rest shape is fixed and no IPAM sizes move)", record.before
        return design, results, record
    p = np.zeros(problem.size)
    current, objectives = design, replayed_objectives(design, results, targets, device)
    for step in range(settings.steps):
        grads = problem.gradients(current, results, targets, device)
        direction = -min_norm_direction(grads)
        if not np.any(direction):
            record.reason = "no direction lowers every target's objective"
            break
        trial_scale, accepted = 1.0, False
        for _ in range(settings.halvings + 1):
            q = problem.clip_step(p, direction * trial_scale / max(np.abs(direction).max(), 1e-300))
            trial = problem.design(q)
            trial_obj = replayed_objectives(trial, results, targets, device)
            if np.all(trial_obj <= objectives) and np.any(trial_obj < objectives):
                p, current, objectives, accepted = q, trial, trial_obj, True
                break
            trial_scale *= 0.5
        if progress is not None:
            progress(step + 1, settings.steps)
        if not accepted:
            record.reason = f"step {step + 1}: no shortened step lowered the objectives without raising one"
            break
        record.steps.append([float(o) for o in objectives])
    if current is design:
        record.reason = record.reason or "no step accepted"
        record.after = record.before
        return design, results, record
    new = control_many(current, targets, device=device, settings=control_settings, passive_ipams=passive_ipams,
                       passive_cells=passive_cells, target_names=target_names)
    record.after = [float(r.objective) for r in new]
    record.max_displacement = float(np.linalg.norm(current.rest.vertices - design.rest.vertices, axis=1).max())
    record.ipam_area = (tuple(problem.area0), tuple(ip.area for ip in current.ipams))
    record.ipam_stiffness = (tuple(problem.k0), tuple(ip.stiffness for ip in current.ipams))
    worse = [j for j, (a, b) in enumerate(zip(record.after, record.before)) if a > b]
    if worse:
        record.reason = (f"re-controlled, target {worse[0]} got worse ({record.after[worse[0]]:.4g} > "
                         f"{record.before[worse[0]]:.4g}): the placed design is kept")
        return design, results, record
    record.kept, record.reason = True, f"{len(record.steps)} step(s) accepted; no target worse after re-control"
    return current, new, record
