"""The designer: automatic design for a set of target shapes (paper section V, Algorithm 1; SPEC section 7).

``design(base, targets, actuators=p)``:
1. initialise (multi-target mode): the run's problem (``controller.problem.Problem``: the targets
   centred once, their names, volumes and radial sampler, built once and passed to every control
   batch, placement and co-design step); sample every target radially through the
   base mesh's vertex directions; normalise each target's radii to unit volume, average them per
   vertex, and scale the result to ``volume_scale`` (0.8) x the smallest target's volume, so the
   membrane is in tension everywhere once inflated. Single-target mode (``initialize=False``) keeps
   the given rest shape (centred). Before the first round the targets are checked against the device
   (``controller.checks``: millimetres against the base, then size against the rest shape and the
   sampled target's volume; once per target in the run), each failure an error naming the fix.
2. p rounds: control the current design to every target (one batch of worlds); compute the scaled
   radial error e = (R - r) / V_t^(1/3) at every face centroid (R: target sampled through the
   achieved face centroid, r: its radius), then place one IPAM and a jamming cell of ``cell_radius``
   around each end (faces whose rest centroids lie within the radius and are in no cell yet), by
   the placement strategy ``settings.placement``, whose decisions the loop applies (``PLACEMENTS``: "simulated", the default, never
   worse than "paper" on any target; "paper", Algorithm 1 as published; "greedy"; docs/placement.md
   describes and measures them; ``register_placement`` adds one).
3. a final control run of the finished design: round p. ``pcc_by_round`` is (p + 1, n_targets).
``result.placement["start_pcc"]``: each target's PCC against the (averaged) rest shape; a target below
0 (anti-correlated, a bad start) is listed in ``bad_start``.

Modules: ``settings`` (DesignSettings, the registry), ``initialize`` (checks, initial rest shape,
design copies), ``placement`` (placements as strategies, the paper's rule, candidate ends),
``per_target`` (the default placement and its refinement rounds), ``greedy`` (the greedy
placement), ``passive_sets`` (which actuators each target's sequence leaves out), ``rounds`` (a run's
shared state and its control rounds), ``loop`` (design), ``result`` (DesignResult, plain data).
"""

from .initialize import copy_design, initial_rest_shape
from .loop import design
from .placement import PLACEMENTS, Decision, PaperPlacement, Placement, PlacementContext, paper_placement, register_placement
from .per_target import PerTargetPlacement, refine_passive
from .greedy import GreedyPlacement, greedy_placement
from .result import DesignResult
from .rounds import DesignRun
from .passive import PassiveSets, passive_from_settings, passive_to_settings
from .design_settings import DesignSettings

__all__ = ["DesignSettings", "DesignResult", "design", "initial_rest_shape", "copy_design", "passive_to_settings",
           "passive_from_settings", "PlacementContext", "paper_placement", "PLACEMENTS", "PassiveSets",
           "greedy_placement", "refine_passive", "Placement", "Decision", "PaperPlacement", "PerTargetPlacement", "GreedyPlacement",
           "register_placement", "DesignRun"]
