"""Jam plans: how the model-based controller reaches the state its refinement starts from.

Jamming is irreversible and path dependent, so the controller tries several plans, refines the air
and IPAM pressures of each, and keeps the best per target. A plan names the start of a sequence:
- ``paper``: the paper's law as it ran (the warm start), its cells jammed when eqs. (13)-(15) said;
- ``never``: from rest, ramp to the warm start's final controls and hold; no cell ever jams;
- ``overinflate<f>`` (e.g. ``overinflate1.5``): from rest, ramp to ``f`` times the warm start's
  final air with its final IPAM pressures, hold until at rest, jam every (non-passive) cell there,
  ramp back to the warm start's final controls and hold. The cells keep the larger, smoother shape
  they had when inflated; shrinking the rest pulls the free membrane in between them.

Where scratch batches settle statically (``SimulationSettings.settle == "static"``), the plans that
start from rest are screened from their equilibria (``plan_starts``): without a jam the ramp's path
does not matter, and ``overinflate`` jams at the equilibrium of its larger air, where its hold comes to
rest. Only a plan that some target keeps runs its trajectory (``plan_trajectory``), so every result
still comes from a recorded, stepped sequence. The warm start's trajectory is the law's own
simulator where it is given (the state a replay of the law's results reaches, bit for bit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DesignError
from .history import History
from .laws import Controls
from .observe import Observer
from .open_loop import replay_simulator
from .trajectory import Trajectory

__all__ = ["parse_plans", "start_plan", "PlanStart", "plan_starts", "plan_trajectory", "PLAN_HELP"]

PLAN_HELP = "'warm' (the warm start's jam times), 'never' or 'overinflate<f>' with f >= 1 (e.g. 'overinflate1.5')"
PLAN_ALIASES = {"paper": "warm"}  # the former name of the warm start's jam times


def parse_plans(text: str) -> list[tuple[str, float]]:
    """``"warm never overinflate1.5"`` -> ``[("warm", 0), ("never", 0), ("overinflate", 1.5)]``."""
    out = []
    for token in str(text).split():
        token = PLAN_ALIASES.get(token, token)
        if token in ("warm", "never"):
            out.append((token, 0.0))
            continue
        factor = None
        if token.startswith("overinflate"):
            try:
                factor = float(token[len("overinflate"):])
            except ValueError:
                factor = None
        if factor is None or not (1.0 <= factor <= 3.0):
            raise DesignError(f"unknown jam plan {token!r} in inverse_plans; each plan is {PLAN_HELP} (f <= 3)")
        out.append(("overinflate", factor))
    if not out:
        raise DesignError(f"inverse_plans names no plan; give one or more of {PLAN_HELP}")
    return out


def _history_from_results(results, host) -> History:
    """A History holding the warm start's rows and frames, to be continued."""
    hist = History(len(results), host)
    for w, res in enumerate(results):
        cols = list(res.history)
        n = len(res.history[cols[0]])
        hist.rows[w] = [{c: res.history[c][k].item() for c in cols} for k in range(n)]
        hist.frames[w] = list(res.frames)
    return hist


def _warm_controls(warm, host) -> Controls:
    """The warm start's final controls, (W,) mol and (W, n_ipam) Pa."""
    air = np.array([r.air_moles for r in warm])
    press = np.stack([r.ipam_pressures for r in warm]) if host.n_ipams else np.zeros((len(warm), 0))
    return Controls(air, press)


def start_plan(plan: tuple[str, float], ctx, warm, warm_simulator=None) -> Trajectory:
    """The main trajectory of ``plan`` at the state its refinement starts from. ``ctx``: the run
    (design, settings, device, sampler, device constants, passive masks); ``warm``: the warm start's
    results (one per target); ``warm_simulator``: the law's simulator at the end of its run (taken
    over by the ``warm`` plan; None: the results are replayed)."""
    name, factor = plan
    W = len(warm)
    host = ctx.host
    c = _warm_controls(warm, host)
    air, press = c.air, c.pressures
    observer = Observer(host, ctx.sampler, W, [r.target.volume() for r in warm])
    if name == "warm":
        sim = warm_simulator if warm_simulator is not None else replay_simulator(ctx.design, warm, device=ctx.device)
        hist = _history_from_results(warm, host)
        step = max(int(r.history["step"][-1]) for r in warm)
        jam_steps = np.stack([r.jam_steps for r in warm]).astype(np.int64).reshape(W, host.n_cells)
        traj = Trajectory(sim, observer, ctx.settings, hist, step, Controls(air.copy(), press.copy()), jam_steps,
                          ctx.passive_ipams, ctx.passive_cells)
        traj.observe()
        return traj
    sim = ctx.new_simulator(W)
    rest = Controls(air=np.full(W, host.rest_air), pressures=np.zeros((W, host.n_ipams)))
    traj = Trajectory(sim, observer, ctx.settings, History(W, host), 0, rest, np.full((W, host.n_cells), -1, np.int64),
                      ctx.passive_ipams, ctx.passive_cells)
    traj.observe()
    if name == "overinflate":
        traj.ramp(factor * air, press)
        traj.settle()
        traj.jam_all()
    traj.ramp(air, press)
    traj.settle()
    return traj


@dataclass
class PlanStart:
    """Where the screen of one plan starts: every target's state and controls, and the plan's
    trajectory (None until a target keeps the plan: ``plan_trajectory`` runs it then)."""

    plan: tuple[str, float]
    states: list  # (W,) model.WorldRef
    controls: Controls
    trajectory: Trajectory | None


def plan_starts(plans: list, ctx, warm, explorer, warm_simulator=None) -> list[PlanStart]:
    """One ``PlanStart`` per plan (module docstring): every trajectory run, or, where scratch batches
    settle statically, the warm start's alone and the others' starts settled (``explorer``, the
    run's ``controller.explore.Explorer``; all ``overinflate`` plans in one batch)."""
    if ctx.settings.simulation.settle != "static":
        trajs = [start_plan(p, ctx, warm, warm_simulator) for p in plans]
        return [PlanStart(p, t.states(), t.controls, t) for p, t in zip(plans, trajs)]
    W, host = len(warm), ctx.host
    warm_controls = _warm_controls(warm, host)
    rest = ctx.new_simulator(W).snapshot() if any(p[0] != "warm" for p in plans) else None  # none for "warm" alone
    over = [p for p in plans if p[0] == "overinflate"]
    jammed = {}
    if over:
        targets = np.tile(np.arange(W), len(over))
        air = np.concatenate([f * warm_controls.air for _, f in over])
        press = np.tile(warm_controls.pressures, (len(over), 1))
        settled = explorer.settle(rest * len(over), air, press, targets)
        cells = np.tile(~ctx.passive_cells, (len(over), 1))
        states = explorer.jammed(settled.states, cells)
        jammed = {p: states[k * W:(k + 1) * W] for k, p in enumerate(over)}
    out = []
    for p in plans:
        if p[0] == "warm":
            t = start_plan(p, ctx, warm, warm_simulator)
            out.append(PlanStart(p, t.states(), t.controls, t))
        else:
            out.append(PlanStart(p, jammed.get(p, rest), warm_controls, None))
    return out


def plan_trajectory(start: PlanStart, ctx, warm) -> Trajectory:
    """The trajectory of ``start``'s plan, run now where it was not yet."""
    if start.trajectory is None:
        start.trajectory = start_plan(start.plan, ctx, warm)
    return start.trajectory
