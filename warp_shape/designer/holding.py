"""``placement="simulated"``: Algorithm 1's actuator sets, each held neutral where it does not help,
then refinement rounds of holds (``designer.refine``); docs/placement.md."""

from __future__ import annotations

from ..controller import control_many
from .placement import PaperPlacement, register_placement
from .refine import ipam_cells, refine_holds
from .selection import Selection

__all__ = ["HoldingPlacement"]


class HoldingPlacement(PaperPlacement):
    """Algorithm 1's sets (placed as ``PaperPlacement`` places them); in each round before the last
    every target is also controlled with the newest set held neutral and keeps the better fit; after
    the last round, refinement rounds of holds. Never worse than "paper" on any target."""

    name = "simulated"
    summary = ("Algorithm 1's sets, each target holding neutral what does not help it, refined in batches of "
               "worlds; never worse than paper on any target (default)")
    uses_candidates = True

    def __init__(self):
        self.held = None  # Selection: what each target holds neutral in the construction rounds

    def hold(self, run, i, round_settings):
        """A round before the last (not the first): each target also controlled with the newest set
        held neutral on top of what it held before, the better of the two recorded; what each target
        holds goes to ``self.held`` and the newest set's record (``held_for``)."""
        if self.held is None:
            self.held = Selection(len(run.targets))
        if i == 0:
            return None
        current, held, names = run.current, self.held, run.names
        new = current.n_ipams - 1
        cells = set(ipam_cells(current, new))

        def hold(results):
            pi = [sorted(held.ipams[t] | {new}) for t in range(len(run.targets))]
            pc = [sorted(held.cells[t] | cells) for t in range(len(run.targets))]
            runs = control_many(current, run.targets, device=run.device, settings=round_settings,
                                progress=run.round_progress(i), passive_ipams=pi, passive_cells=pc, target_names=names)
            out = []
            for t, (r_all, r_held) in enumerate(zip(results, runs)):
                keep = r_held.objective < r_all.objective
                held.ipams[t], held.cells[t] = (set(pi[t]), set(pc[t])) if keep else (set(), set())
                out.append(r_held if keep else r_all)
            run.added[-1]["held_for"] = [names[t] for t in range(len(run.targets)) if new in held.ipams[t]]
            return out
        return hold

    def finish(self, run, i):
        """The refinement rounds after the last round; a target's refined result replaces its last-round
        result (``on_round`` is told again)."""
        if run.settings.refine_rounds <= 0 or run.current.n_ipams == 0:
            return
        held = self.held or Selection(len(run.targets))
        info, rounds = run.info, run.rounds
        info["paper_objective"] = [r.objective for r in rounds[-1]]  # every actuator in use: Algorithm 1's fit
        refined, info["refinement"], info["refinement_stopped"] = refine_holds(
            run.current, rounds[-1], run.selection, list(zip(held.passive_ipams(), held.passive_cells())),
            [a["target"] for a in run.added], targets=run.targets, names=run.names, settings=run.settings,
            control_settings=run.control_settings, device=run.device, progress=run.round_progress(i),
            recorder=run.recorder)
        if any(a is not b for a, b in zip(refined, rounds[-1])):
            rounds[-1] = refined
            if run.on_round is not None:
                run.on_round(i, run.designs[-1], refined)

    @classmethod
    def describe(cls, info):
        K = info.get("candidates")
        refine = (f", then refinement rounds of K = {K} holds per target, each round one batch of worlds"
                  if "refinement" in info else ", no refinement rounds")
        return (f" (Algorithm 1's actuator sets, each held neutral for the targets it does not help{refine}: "
                "no target ends worse than under Algorithm 1)")


register_placement(HoldingPlacement)
