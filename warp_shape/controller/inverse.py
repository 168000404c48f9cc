"""``method="inverse"``: model-based control of the air, the IPAM pressures and the jamming plan.

1. Warm start: the paper's law (``method="paper"``), as it is.
2. Jam plans (``controller.plans``, setting ``inverse_plans``): the warm start's jam times, never jamming,
   over-inflating and jamming every cell; each plan's main trajectory runs in its own simulator
   (one world per target) and records every control step. With static scratch settles a plan that
   starts from rest is screened from its equilibria and runs its trajectory only if a target keeps it.
3. Screening: every plan's state settled and measured (all plans and targets in one batch); the
   ``PLANS_REFINED`` best plans of each target go on.
4. Refinement (``controller.refine``): bounded damped Gauss-Newton on the fit objective's residual
   with the settled shape's finite-difference Jacobian, each iteration one or two batches of worlds
   (all plans and targets at once); it stops when the objective improves by less than
   ``inverse_tolerance`` (relative), when no step improves it, or after ``inverse_iterations``.
5. Per target the plan whose refined controls fit best: its trajectory ramps to them within the
   rate limits and holds them until the membrane is at rest (``settle_speed``); the fit
   is measured there. If it does not beat the warm start, the paper law's result is returned
   unchanged and the reason says so: the result never ends worse than its warm start.
Passive IPAMs are held neutral (masked out of their worlds: no force) and passive cells never jam throughout, so an actuator held neutral
leaves the controls of the others as they were. ``result.refinement`` tells what happened.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..display import Design
from ..model import HostModel, host_model
from ..sampling import RadialSampler
from .explore import Explorer
from .plans import parse_plans, plan_starts, plan_trajectory
from .problem import as_problem
from .refine import STOP_LIMIT, Refined, refine, uses_adjoint
from .result import ControlResult, ScreenResult
from .control_settings import ControlSettings
from .worlds import mask_passive, passive_masks

__all__ = ["control_inverse", "predict_inverse", "PLANS_REFINED"]

PLANS_REFINED = 2  # plans refined per target: those that fit best, settled, before refining


@dataclasses.dataclass
class _Run:
    """What every part of one inverse run shares."""

    design: Design
    settings: ControlSettings
    device: str
    sampler: RadialSampler
    host: HostModel
    passive_ipams: np.ndarray  # (W, n_ipam) bool
    passive_cells: np.ndarray  # (W, n_cell) bool

    def new_simulator(self, worlds: int):
        from ..simulator import Simulator

        sim = Simulator(self.design, device=self.device, settings=self.settings.simulation, worlds=worlds)
        if self.passive_ipams is not None and worlds == len(self.passive_ipams):  # one world per target
            mask_passive(sim, self.passive_ipams, self.passive_cells)
        return sim


def _screen(start: np.ndarray, keep: int) -> np.ndarray:
    """(P, W) bool: per target the ``keep`` plans with the lowest objective before refining."""
    out = np.zeros(start.shape, dtype=bool)
    for w in range(start.shape[1]):
        out[np.argsort(start[:, w], kind="stable")[:keep], w] = True
    return out


def _explorer(ctx: _Run, warm) -> Explorer:
    s = ctx.settings
    volumes = np.array([r.target.volume() for r in warm])
    return Explorer(ctx.design, s.simulation, ctx.device, ctx.sampler, ctx.host, volumes, ctx.passive_ipams,
                    s.inverse_settle_steps, s.control_period)


def _refine_all(ctx: _Run, ex: Explorer, starts: list, warm) -> tuple[list[Refined], int]:
    """Screen every (plan, target) pair in one batch (its start settled and measured), then refine the
    ``PLANS_REFINED`` best plans of every target in one set of batches; one ``Refined`` per plan, and
    the world-steps simulated for it."""
    W, P, s, n = len(warm), len(starts), ctx.settings, ctx.host.n_ipams
    air = np.concatenate([t.controls.air for t in starts])
    press = np.concatenate([t.controls.pressures for t in starts]).reshape(P * W, n)
    targets = np.tile(np.arange(W), P)
    S = ex.settle([st for t in starts for st in t.states], air, press, targets)
    keep = _screen(S.objective.reshape(P, W), PLANS_REFINED).reshape(-1)
    idx = np.flatnonzero(keep)
    ref = refine(ex, [S.states[c] for c in idx], air[idx], press[idx], targets[idx],
                 np.tile(~ctx.passive_ipams, (P, 1))[idx], s.inverse_iterations, s.inverse_tolerance,
                 gradient=s.inverse_gradient)
    out = []
    for p in range(P):
        sl = slice(p * W, (p + 1) * W)
        r = Refined(air=air[sl].copy(), pressures=press[sl].copy(), start_objective=S.objective[sl].copy(),
                    objective=S.objective[sl].copy(), start_mare=S.mare[sl].copy(), mare=S.mare[sl].copy(),
                    iterations=np.zeros(W, dtype=np.int64),
                    stop=[f"not refined: {PLANS_REFINED} other plans fitted better before refining"] * W,
                    saturated=[[] for _ in range(W)], trace=[[] for _ in range(W)])
        for i in np.flatnonzero((idx >= p * W) & (idx < (p + 1) * W)):
            w = idx[i] - p * W
            for name in ("air", "pressures", "start_objective", "objective", "start_mare", "mare", "iterations"):
                getattr(r, name)[w] = getattr(ref, name)[i]
            r.stop[w], r.saturated[w], r.trace[w] = ref.stop[i], ref.saturated[i], ref.trace[i]
        out.append(r)
    return out, ex.world_steps


def _result(traj, w: int, warm: ControlResult, plan: str, ref, w_ref: int) -> ControlResult:
    """World ``w`` of a finished trajectory as a control result (fields of ``warm`` replaced).
    Converged: at rest, the refinement stopped by itself (not at its iteration limit), nothing saturated."""
    obs, s = traj.last, traj.settings
    x, sampled = obs.positions[w].copy(), obs.sampled[w].copy()
    vol, vol_t = obs.volume[w], obs.target_volume[w]
    at_rest, stop, saturated = bool(traj.settled[w]), ref.stop[w_ref], list(ref.saturated[w_ref])
    speed = f"largest vertex speed {obs.max_speed[w] * 1e3:.2g} mm/s"
    rest = (f"at rest ({speed} < {s.settle_speed * 1e3:g} mm/s)" if at_rest else
            f"not at rest: {speed} after holding the refined controls (max_settle_steps {s.max_settle_steps})")
    converged = at_rest and stop != STOP_LIMIT and not saturated
    head = ("converged" if converged else "stopped by a limit: " + ", ".join(saturated) if saturated
            else "not converged")
    reason = (f"{head}; {rest}; model-based refinement of plan {plan!r}: {stop} after "
              f"{int(ref.iterations[w_ref])} step(s)")
    return dataclasses.replace(
        warm, achieved=warm.achieved.copy_with(x), sampled_target=warm.achieved.copy_with(sampled),
        objective=float(obs.objective[w]), pcc=float(obs.pcc[w]), mare=float(obs.mare[w]), mpre=float(obs.mpre[w]),
        volume_error=float((vol - vol_t) / vol_t), ipam_forces=obs.ipam_forces[w].copy(),
        ipam_pressures=traj.controls.pressures[w].copy(), air_moles=float(traj.controls.air[w]),
        jammed=obs.jammed[w].copy().astype(bool), jam_steps=traj.jam_steps[w].copy(), converged=converged,
        reason=reason, saturated=saturated, settled=at_rest, max_speed=float(obs.max_speed[w]),
        control_steps=int(obs.step), history=traj.history.columns(w), frames=traj.history.frame_stack(w))


def _info(w: int, names: list, refined: list, best: int, warm_obj: float, objective: float) -> dict:
    """``result.refinement`` of target ``w``: the plan kept, every plan's settled fit before and after
    refining (scratch worlds), the stop reason, the saturated actuators."""
    ref = refined[best]
    return dict(method="inverse", plan=names[best], warm_objective=warm_obj, objective=objective,
                predicted_objective=float(ref.objective[w]), iterations=int(ref.iterations[w]), stop=ref.stop[w],
                saturated=list(ref.saturated[w]), fell_back=False,
                plans={n: float(r.objective[w]) for n, r in zip(names, refined)},
                plans_before={n: float(r.start_objective[w]) for n, r in zip(names, refined)},
                plans_mare={n: float(r.mare[w]) for n, r in zip(names, refined)},
                plans_mare_before={n: float(r.start_mare[w]) for n, r in zip(names, refined)})


def _finish_and_choose(ctx: _Run, starts: list, names: list, refined: list, warm: list) -> list[ControlResult]:
    """Per target the plan whose refined controls fit best: its trajectory (run now where it was not
    yet) ramps to them and holds them until at rest, and the fit measured there is kept unless it does
    not beat the warm start."""
    pred = np.array([r.objective for r in refined])  # (P, W)
    best = np.argmin(pred, axis=0)
    trajs = {}
    for p in sorted(set(best.tolist())):
        t = trajs[p] = plan_trajectory(starts[p], ctx, warm)
        press = refined[p].pressures
        if ctx.host.n_ipams:  # passive IPAMs: from where the trajectory holds them (neutral), as they started
            press = np.where(ctx.passive_ipams, t.controls.pressures, press)
        t.ramp(refined[p].air, press)
        t.settle()
    out = []
    ran = [n for n, st in zip(names, starts) if st.trajectory is not None]
    for w, base in enumerate(warm):
        p = int(best[w])
        cand = _result(trajs[p], w, base, names[p], refined[p], w)
        obj, warm_obj = cand.objective, base.objective
        info = _info(w, names, refined, p, warm_obj, obj)
        info["trajectories"] = ran  # the plans whose trajectories ran (the others: screened from equilibria)
        if obj < warm_obj:
            out.append(dataclasses.replace(cand, refinement=info))
            continue
        info.update(fell_back=True, objective=warm_obj)
        out.append(dataclasses.replace(
            base, refinement=info,
            reason=f"{base.reason}; the model-based refinement did not improve on the paper's law (plan "
                   f"{names[p]!r}: objective {obj:.5g} vs {warm_obj:.5g}), so its result is kept"))
    return out


def _log(recorder, prefix: str, design: Design, results: list, names, settings, sampler: RadialSampler) -> None:
    """Log the final control sequences (every recorded row of every target) to ``recorder``; the
    targets are sampled again through each recorded frame."""
    W = len(results)
    recorder.begin_run(design=design, targets=[r.target for r in results], target_names=names, prefix=prefix,
                       settings=settings)
    for w, res in enumerate(results):
        h, frames = res.history, res.frames
        cols = list(h)
        sampled = sampler.sample_worlds(frames.astype(np.float64), np.full(len(frames), w))
        for k in range(len(frames)):
            rows = [[{c: h[c][k] for c in cols}] if v == w else [] for v in range(W)]
            x = np.broadcast_to(frames[k], (W,) + frames[k].shape)
            s = np.broadcast_to(sampled[k], (W,) + frames[k].shape)
            recorder.log_control_step(step=int(h["step"][k]), time=float(h["time"][k]), positions=x, sampled=s,
                                      rows=rows, done=np.arange(W) != w)
    recorder.end_run(results)


def _prepare(design: Design, settings: ControlSettings, device: str, warm: list, targets=None):
    """The run's context, its jam plans (``settings.inverse_plans``; no ``overinflate`` where no cell can
    jam) and its scratch explorer; ``targets``: the warm start's targets (a ``Problem``, whose sampler
    is used; None: the warm results' targets)."""
    plans = parse_plans(settings.inverse_plans)
    sampler = as_problem([r.target for r in warm] if targets is None else targets, device=device, centre=False).sampler
    probe = _Run(design, settings, device, sampler, None, None, None)
    host = host_model(design)
    pi, pc = passive_masks(warm, host.n_ipams, host.n_cells)
    ctx = dataclasses.replace(probe, host=host, passive_ipams=pi, passive_cells=pc)
    if not (~pc).any():  # no cell to jam: over-inflating would only repeat "never"
        plans = [p for p in plans if p[0] != "overinflate"] or plans
    names = [f"{n}{f:g}" if n == "overinflate" else n for n, f in plans]
    return ctx, plans, names, _explorer(ctx, warm)


def control_inverse(design: Design, targets, *, device: str, settings: ControlSettings, warm_start: list,
                    warm_simulator=None, progress=None, recorder=None, recorder_prefix: str = "control",
                    passive_ipams=(), passive_cells=(), target_names=None) -> list[ControlResult]:
    """Drive ``design`` to every target with the model-based controller (module docstring), starting
    from ``warm_start``, a control law's results for the same targets and passive actuators, and
    ``warm_simulator``, the law's simulator at the end of that run (None: the results are replayed;
    ``controller.loop.run_law(..., keep_simulator=True)`` gives both); the other arguments are those
    of ``control_many`` (the recorder logs the final sequences once they are chosen)."""
    t0 = time.perf_counter()
    warm = warm_start
    ctx, plans, names, ex = _prepare(design, settings, device, warm, targets)
    starts = plan_starts(plans, ctx, warm, ex, warm_simulator)
    refined, world_steps = _refine_all(ctx, ex, starts, warm)
    results = _finish_and_choose(ctx, starts, names, refined, warm)
    for w, res in enumerate(results):
        m = 1 + int((~ctx.passive_ipams[w]).sum()) if ctx.host.n_ipams else 1
        res.refinement.update(wall_s=time.perf_counter() - t0, world_steps=int(world_steps),
                              evaluations=int(ex.evaluations), adjoint_iterations=int(ex.adjoint_iterations),
                              gradient="adjoint" if uses_adjoint(settings.inverse_gradient, m,
                                                                 ex.sim_settings.settle) else "finite-difference")
    if recorder is not None:
        names = list(target_names) if target_names is not None else [f"target{j}" for j in range(len(results))]
        _log(recorder, recorder_prefix, design, results, names, settings, ctx.sampler)
    return results


def predict_inverse(design: Design, *, device: str, settings: ControlSettings, warm_start: list,
                    warm_simulator=None, targets=None) -> list[ScreenResult]:
    """The fit the model-based controller predicts for every target of ``warm_start`` (steps 1-4 of
    the module docstring, no trajectory run): per target the plan whose refined controls fit best in
    the scratch batch and that fit, or the warm start's where it is not better (as ``control_inverse``
    falls back). A screen's estimate, not a control sequence (``ScreenResult``); ``targets``: the warm
    start's (``control_inverse``'s)."""
    warm = warm_start
    ctx, plans, names, ex = _prepare(design, settings, device, warm, targets)
    starts = plan_starts(plans, ctx, warm, ex, warm_simulator)
    refined, _ = _refine_all(ctx, ex, starts, warm)
    pred = np.array([r.objective for r in refined])  # (P, W)
    out = []
    for w, base in enumerate(warm):
        p = int(np.argmin(pred[:, w]))
        obj, warm_obj = float(pred[p, w]), float(base.objective)
        info = _info(w, names, refined, p, warm_obj, obj)
        if obj >= warm_obj:  # as control_inverse: the paper law's result is kept
            info.update(fell_back=True, objective=warm_obj)
        out.append(ScreenResult(objective=info["objective"], plan=names[p], predicted=True, refinement=info))
    return out
