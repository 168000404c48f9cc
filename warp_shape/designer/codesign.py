"""Co-design after placement: the shared rest shape and the IPAM sizes descended by exact gradients.

Each target's final control sequence is replayed open loop on the design and differentiated
(``gradients.gradient``). The rest shape moves by smooth radial modes (each vertex scaled by
exp(sum_m c_m Y_m(u)), Y_m the polynomials of degree 1..``degree`` in the rest direction u,
orthonormal over the vertices), so it stays closed, star-shaped and smooth; the rest volume stays
within the initialisation's bound. IPAM areas and stiffnesses move in log scale within
``size_bounds`` x their placed values. A step follows the common descent direction of the targets
(the min-norm point of their gradients' convex hull), is shortened until no target's replayed
objective rises (tried first shorter after a step that realised little of its predicted decrease),
and the design is re-controlled with the design's controller at the end of each round; a target
whose re-control ends above its held sequence replayed keeps that sequence, and a round whose steps
stopped gaining is the last. A round is kept only if no target's final objective is worse than
before it. docs/gradients.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..controller import ControlSettings, control_many
from ..controller.problem import as_problem, take
from ..controller.open_loop import replay_result
from ..controller.shard import available_cores, run_jobs
from ..display import Design
from ..gradients.api import replay_gradient
from ..gradients.differentiable_replay import plan_replay
from ..mesh import TriMesh
from ..objectives.radial import fit_objective_and_gradient
from .design_settings import CODESIGN_MODES

__all__ = ["CODESIGN_MODES", "CodesignSettings", "CodesignProblem", "codesign", "radial_modes", "min_norm_direction",
           "first_length", "volume_gradient", "replayed", "replayed_objectives", "round_end"]



@dataclass(frozen=True)
class CodesignSettings:
    """Co-design's parameters: ``rounds`` of at most ``steps`` descent steps each (every round ends
    with a re-control of every target; a round whose last step gained less than ``min_gain`` is the last), ``degree`` of the radial modes, the largest
    radial change per step ``max_radial_step`` (relative), the largest IPAM size change per step
    ``max_size_step`` (in log scale) and the IPAM size bounds ``size_bounds`` (x the placed value),
    ``halvings`` step shortenings tried before co-design stops, and ``min_gain``: a round ends after a
    step that lowered no target's replayed objective by more than this fraction (a gain below the
    re-control's own noise of about 1 %, docs/gradients.md)."""

    steps: int = 8
    rounds: int = 2
    degree: int = 4
    max_radial_step: float = 0.03
    max_size_step: float = 0.3
    size_bounds: tuple = (0.5, 2.0)
    halvings: int = 3
    min_gain: float = 0.005
    move_rest: bool = True  # False: the rest shape is the user's (single-target mode); only sizes move


@dataclass
class CodesignRecord:
    """What co-design did: the mode, each accepted step's replayed objectives, each round's re-control
    (``recontrols``: after which step, every target's objective, the targets whose held sequence
    replayed beat their re-control (``held``), whether the round was kept), the objectives
    before and after (the design's controller), the rest shape's largest displacement (m), the IPAM
    sizes before and after, whether the co-designed design was kept and why."""

    mode: str
    steps: list = field(default_factory=list)
    recontrols: list = field(default_factory=list)
    before: list = field(default_factory=list)
    after: list = field(default_factory=list)
    max_displacement: float = 0.0
    ipam_area: tuple = ((), ())
    ipam_stiffness: tuple = ((), ())
    kept: bool = False
    reason: str = ""

    def as_dict(self) -> dict:
        return dict(mode=self.mode, steps=self.steps, recontrols=self.recontrols, before=self.before, after=self.after,
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


def volume_gradient(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) d(enclosed volume)/d(vertex) of the closed mesh (``x``, ``faces``): per face corner
    a of (a, b, c), (x_b x x_c) / 6, summed over the faces at each vertex."""
    out = np.zeros_like(x)
    p = x[faces]
    for k in range(3):
        np.add.at(out, faces[:, k], np.cross(p[:, (k + 1) % 3], p[:, (k + 2) % 3]) / 6.0)
    return out


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
        # a rest shape placed at the volume bound stays at it (every trial scaled to it): the objective
        # of the scaled design is smooth, and so is its gradient (``chain``)
        self.hold_volume = bool(len(self.modes)) and design.rest.volume() >= volume_bound * (1.0 - 1e-9)
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
        if M and (vol > self.volume_bound or self.hold_volume):
            rest = rest.scaled((self.volume_bound / vol) ** (1.0 / 3.0))
        n = self.base.n_ipams
        area = self.area0 * np.exp(p[M:M + n]) if self.sizes else self.area0
        k = self.k0 * np.exp(p[M + n:]) if self.sizes else self.k0
        return self.base.replace(rest=rest, ipams=[dataclasses.replace(ip, stiffness=float(k[i]), area=float(area[i]))
                                                   for i, ip in enumerate(self.base.ipams)])

    def chain(self, design: Design, values: dict) -> np.ndarray:
        """d objective / d parameters from the gradient's values on ``design``."""
        x = design.rest.vertices
        g_modes = self.modes @ np.einsum("vi,vi->v", values["rest_positions"], x)
        if self.hold_volume:
            # the design is scaled to the volume bound: the gradient of the scaled design
            # x (V_b / V(x))^(1/3), whose radial part d/dc_m is sum_v (g_v . x_v) Y_m - J_s dV/dc_m / (3 V)
            # with J_s = sum_v g_v . x_v (the objective's response to a uniform scale)
            dvol = self.modes @ np.einsum("vi,vi->v", volume_gradient(x, design.rest.faces), x)
            uniform = float(np.einsum("vi,vi->", values["rest_positions"], x))
            g_modes = g_modes - uniform * dvol / (3.0 * design.rest.volume())
        if not self.sizes:
            return g_modes
        area = np.array([ip.area for ip in design.ipams])
        k = np.array([ip.stiffness for ip in design.ipams])
        return np.concatenate([g_modes, values["ipam_area"] * area, values["ipam_stiffness"] * k])

    def gradients(self, design: Design, results, targets, device: str = "cpu", plans=None) -> np.ndarray:
        """(T, P) d objective / d parameters of each target's sequence replayed on ``design`` (one job
        per target on the run's workers where they are running); ``plans``: each sequence's replay plan
        on ``design`` where it was made already (``replayed``), so only the adjoints run."""
        wrt = ("rest_positions", "ipam_area", "ipam_stiffness")
        plans = [None] * len(results) if plans is None else plans
        values = run_jobs(_gradient_job, [(design, r, t, wrt, device, pl) for r, t, pl in zip(results, targets, plans)])
        return np.stack([self.chain(design, v) for v in values])

    def limit_step(self, step: np.ndarray) -> np.ndarray:
        """``step`` scaled down (as a whole) to at most ``max_radial_step`` radial change and
        ``max_size_step`` log size change."""
        M, s = len(self.modes), self.settings
        radial = np.abs(step[:M] @ self.modes).max() if M else 0.0
        scale = min(1.0, s.max_radial_step / radial) if radial > 0 else 1.0
        if self.n_sizes:
            big = np.abs(step[M:]).max()
            scale = min(scale, s.max_size_step / big) if big > 0 else scale
        return step * scale

    def bounded(self, q: np.ndarray) -> np.ndarray:
        """``q`` with the IPAM log sizes clipped into ``size_bounds``."""
        q = q.copy()
        if self.n_sizes:
            M, (lo, hi) = len(self.modes), np.log(self.settings.size_bounds)
            q[M:] = np.clip(q[M:], lo, hi)
        return q


def first_length(objectives: np.ndarray, slopes: np.ndarray, longest: float = 1.0) -> float:
    """The fraction of a step tried first: half the length at which the first-order model of the
    objective that falls fastest relative to its value reaches zero (each objective is an RMS of
    residuals, so its linear model reaches zero at J / |dJ/ds|), at most ``longest`` (the length the
    step before was accepted at; 1: the whole step)."""
    falling = slopes < 0
    if not np.any(falling):
        return float(longest)
    return float(min(longest, 0.5 * np.min(objectives[falling] / -slopes[falling])))


#: the precision of co-design's gradients and of the replays that accept its steps (their plans are
#: the gradients' forward replays)
PRECISION = "float64"


def _gradient_job(design: Design, result, target, wrt, device: str, plan=None, *, progress=None) -> dict:
    # on a CPU the adjoint recomputes on a second thread even on a run's worker: where one target's
    # sequence is longer than the others', the cores their jobs leave idle serve it (the same gradient
    # bit for bit); elsewhere the gradient's own rule (None)
    threads = 2 if str(device).startswith("cpu") and available_cores() >= 2 else None
    return replay_gradient(design, result, target, wrt, precision=PRECISION, device=device, plan=plan,
                           threads=threads).values


def _objective_job(design: Design, result, target, device: str, *, progress=None):
    # ``target``: a centred mesh or the run's problem of that one target (whose sampler a worker builds once)
    plan = plan_replay(design, result, precision=PRECISION, device=device)
    problem = as_problem(target, device=device, centre=False)
    return float(fit_objective_and_gradient(plan.final, problem.sampler, 0, design.rest.faces,
                                            problem.volumes[0])[0]), plan


def _round_end_job(design: Design, result, target, device: str, held: bool, *, progress=None):
    # a held sequence replayed as the product replays it (a result), else the next round's start (objective, plan)
    return replay_result(design, result, device=device) if held else _objective_job(design, result, target, device)


def round_end(design: Design, new: list, held_results, targets, replays, device: str, again: bool):
    """A round's end on ``design``: the re-controlled results ``new``, each target whose re-control ends
    above its held sequence's replayed objective (``replays``: (objectives, plans) of the sequences
    ``held_results`` on ``design``) given that sequence as it replays where it fits better. With ``again``
    (another round follows), also the next round's start replays: a held target's is the one it has
    (the same sequence on the same design), the others' run in the same batch of jobs as the held
    replays. Returns (results, held targets, the next round's (objectives, plans) or None)."""
    objectives, plans = replays
    new = list(new)
    above = {j for j in range(len(new)) if new[j].objective > objectives[j]}
    order = [j for j in range(len(new)) if j in above or again]
    out = dict(zip(order, run_jobs(_round_end_job, [(design, held_results[j] if j in above else new[j],
                                                      take(targets, [j]), device, j in above) for j in order])))
    held = [j for j in sorted(above) if out[j].objective < new[j].objective]  # the held sequence fits better
    for j in held:
        new[j] = out[j]
    if not again:
        return new, held, None
    lost = [j for j in sorted(above) if j not in held]  # re-controlled after all: their own start replays
    out.update(zip(lost, run_jobs(_objective_job, [(design, new[j], take(targets, [j]), device) for j in lost])))
    return new, held, _split([(objectives[j], plans[j]) if j in held else out[j] for j in range(len(new))])


def _split(pairs) -> tuple:
    """[(objective, plan)] as ((T,) objectives, [T] plans)."""
    return np.array([o for o, _ in pairs]), [pl for _, pl in pairs]


def replayed(design: Design, results, targets, device: str = "cpu"):
    """((T,) the objective of each result's sequence replayed open loop on ``design`` in ``PRECISION``,
    [T] their replay plans, for the gradients there): one job per target on the run's workers where
    they are running."""
    return _split(run_jobs(_objective_job, [(design, r, take(targets, [j]), device) for j, r in enumerate(results)]))


def replayed_objectives(design: Design, results, targets, device: str = "cpu") -> np.ndarray:
    """(T,) the objective of each result's sequence replayed open loop on ``design`` (``replayed``)."""
    return replayed(design, results, targets, device)[0]


#: a step whose worst target realised less than this fraction of its first-order predicted decrease has
#: met the objectives' curvature: the next step is tried first at half its length (on the default problem
#: the two trials that failed each followed such a step, at 0.28 and 0.30; the others realised 0.4-0.6)
SHRINK_BELOW = 0.4


def next_longest(length: float, predicted: np.ndarray, realised: np.ndarray) -> float:
    """The longest first trial of the next step after a step accepted at ``length``: ``length``, or half of
    it where a target whose objective was predicted to fall (``predicted`` > 0, the first-order decrease)
    realised less than ``SHRINK_BELOW`` of it (``realised``: the replayed decrease)."""
    falling = predicted > 0
    if np.any(falling) and np.min(realised[falling] / predicted[falling]) < SHRINK_BELOW:
        return 0.5 * length
    return length


@dataclass
class Descent:
    """Where a round's descent ended: the parameters ``p``, their ``design``, its ``replays`` (objectives,
    plans), the ``steps`` accepted, why it stopped (``stop``; ``settled``: a step gained less than
    ``min_gain``, so the objectives have stopped falling) and the next step's longest first trial."""

    p: np.ndarray
    design: Design
    replays: tuple
    steps: int = 0
    stop: str = ""
    settled: bool = False
    longest: float = 1.0


def _step(problem: CodesignProblem, at: Descent, results, targets, settings, device):
    """One descent step from ``at``: (accepted (q, design, objectives, plans), the next step's longest first
    trial) or (None, why none was accepted)."""
    objectives, plans = at.replays
    grads = problem.gradients(at.design, results, targets, device, plans)
    direction = -min_norm_direction(grads)
    if not np.any(direction):
        return None, "no direction lowers every target's objective"
    full = problem.limit_step(direction / np.abs(direction).max())
    slopes = grads @ full
    length = first_length(objectives, slopes, at.longest)
    for _ in range(settings.halvings + 1):
        q = problem.bounded(at.p + full * length)
        trial = problem.design(q)
        trial_obj, trial_plans = replayed(trial, results, targets, device)
        if np.all(trial_obj <= objectives) and np.any(trial_obj < objectives):
            return (q, trial, trial_obj, trial_plans), next_longest(length, -length * slopes, objectives - trial_obj)
        length *= 0.5
    return None, "no shortened step lowered the objectives without raising one"


def _descend(problem: CodesignProblem, at: Descent, results, targets, settings, device, record, progress,
             done: int) -> Descent:
    """Up to ``settings.steps`` accepted steps from ``at`` with ``results``' sequences held, each tried
    first at no more than ``at.longest`` (the length the step before was accepted at, halved after a step
    that met the curvature, ``next_longest``). Returns where it ended (``Descent``)."""
    at = Descent(at.p, at.design, at.replays, longest=at.longest)
    for step in range(settings.steps):
        before = at.replays[0]
        accepted, longest = _step(problem, at, results, targets, settings, device)
        if progress is not None:
            progress(done + step + 1, settings.steps * settings.rounds)
        if accepted is None:
            at.stop = longest if longest.startswith("no direction") else f"step {len(record.steps) + 1}: {longest}"
            break
        q, trial, objectives, plans = accepted
        at = Descent(q, trial, (objectives, plans), at.steps + 1, longest=longest)
        record.steps.append([float(o) for o in objectives])
        if np.max(1.0 - objectives / before) <= settings.min_gain:
            at.stop = (f"step {len(record.steps)}: no target's objective fell by more than "
                       f"{settings.min_gain:.1%}")
            at.settled = True
            break
    return at


def codesign(design: Design, targets, results, *, mode: str = "rest+ipams", volume_bound: float,
             control_settings: ControlSettings, passive_ipams, passive_cells, device: str = "cpu",
             settings: CodesignSettings | None = None, target_names=None, progress=None):
    """Co-design ``design`` (placed; ``results``: its final control result per centred target) in
    ``mode`` (see ``CODESIGN_MODES``): rounds of descent steps with every target's sequence held, each
    round ended by re-controlling every target with ``control_settings`` on the design reached (a
    target whose re-control ends above its held sequence replayed keeps that sequence,
    ``replay_result``); a round whose last step gained less than ``settings.min_gain`` is the last; a round
    is kept only if no target's objective is higher than before it. Returns (design, results,
    CodesignRecord): the last kept round's design and results, else the input ones."""
    settings = settings or CodesignSettings()
    record = CodesignRecord(mode=mode, before=[float(r.objective) for r in results])
    if mode == "off":
        record.reason = "co-design off"
        return design, results, record
    problem = CodesignProblem(design, mode, settings, volume_bound)
    if problem.size == 0:
        record.reason, record.after = "nothing to co-design (the rest shape is fixed and no IPAM sizes move)", record.before
        return design, results, record
    at = Descent(np.zeros(problem.size), design, replayed(design, results, targets, device))
    kept, kept_results, kept_obj = design, results, np.array(record.before)
    reason = ""
    for r in range(settings.rounds):
        at = _descend(problem, at, kept_results, targets, settings, device, record, progress, r * settings.steps)
        if at.steps == 0:
            reason = at.stop
            break
        last = r + 1 == settings.rounds or at.settled  # objectives that stopped falling: no round after this one
        new = control_many(at.design, targets, device=device, settings=control_settings, passive_ipams=passive_ipams,
                           passive_cells=passive_cells, target_names=target_names)
        new, held, replays = round_end(at.design, new, kept_results, targets, at.replays, device, not last)
        new_obj = np.array([x.objective for x in new])
        worse = np.flatnonzero(new_obj > kept_obj)
        record.recontrols.append(dict(step=len(record.steps), objectives=[float(o) for o in new_obj], held=held,
                                      kept=not len(worse)))
        if len(worse):
            j = int(worse[0])
            reason = (f"round {r + 1}: re-controlled, target {j} got worse ({new_obj[j]:.4g} > {kept_obj[j]:.4g}): "
                      + ("the placed design is kept" if kept is design else f"round {r}'s design is kept"))
            break
        kept, kept_results, kept_obj = at.design, new, new_obj  # the next round descends with these sequences held
        reason = at.stop
        if last:
            break
        at = Descent(at.p, at.design, replays, longest=at.longest)
    record.after = [float(o) for o in kept_obj]
    if kept is design:
        record.reason = reason or "no step accepted"
        return design, results, record
    rounds = sum(rc["kept"] for rc in record.recontrols)
    record.max_displacement = float(np.linalg.norm(kept.rest.vertices - design.rest.vertices, axis=1).max())
    record.ipam_area = (tuple(problem.area0), tuple(ip.area for ip in kept.ipams))
    record.ipam_stiffness = (tuple(problem.k0), tuple(ip.stiffness for ip in kept.ipams))
    record.kept = True
    record.reason = (f"{rounds} round(s) kept ({len(record.steps)} step(s) accepted); no target worse after "
                     f"re-control" + (f"; then {reason}" if reason else ""))
    return kept, kept_results, record
