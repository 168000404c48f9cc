"""The designer: automatic design for a set of target shapes (paper section V, Algorithm 1; SPEC section 7).

``design(base, targets, actuators=p)``:
1. initialise (multi-target mode): centre the targets; sample every target radially through the
   base mesh's vertex directions; normalise each target's radii to unit volume, average them per
   vertex, and scale the result to ``volume_scale`` (0.8) x the smallest target's volume, so the
   membrane is in tension everywhere once inflated. Single-target mode (``initialize=False``) keeps
   the given rest shape (centred). Before the first round the targets are checked against the device
   (``controller.checks``: millimetres against the base, then size against the rest shape and the
   sampled target's volume), each failure an error naming the fix.
2. p rounds: control the current design to every target (one batch of worlds); compute the scaled
   radial error e = (R - r) / V_t^(1/3) at every face centroid (R: target sampled through the
   achieved face centroid, r: its radius), then place one IPAM and a jamming cell of ``cell_radius``
   around each end (faces whose rest centroids lie within the radius and are in no cell yet), by
   ``settings.placement``:
   - "paper" (Algorithm 1 as published): the free face (no cell, no IPAM end) with the largest |e|
     over all targets is one end; the other is, in that target, the free face with the largest error
     of the same sign among faces at least ``min_angle`` (120 degrees) away seen from the origin on
     the REST shape. Every target uses every actuator.
   - "simulated" (default): Algorithm 1's sets, as "paper" places them; in each round before the
     last every target is also controlled with the newest set held neutral (masked out of its
     world) and keeps the better fit, so no round makes a target worse (``result.added[k]
     ["held_for"]``). After the final control run, refinement rounds try ``candidates`` (K) holds
     per target in one batch of worlds (screened by quick model-based control) and keep those the
     design's controller confirms (``designer.refine``): on every target the final fit is at least
     Algorithm 1's.
   - "greedy": ``candidates`` (K) sets, first ends from the largest-error free faces of every
     target, are controlled to every target in one batch of K x targets worlds of one union model
     with per-world actuator masks; the set that lowers the summed fit objective most is kept, left
     out (held neutral) for the targets it does not help, so no round makes a target worse; the
     design stops early when no candidate gains more than ``min_gain``. Every candidate's scores are
     in ``result.placement["rounds"]`` (``designer.greedy``). It trades targets off: a target can end
     worse than under Algorithm 1 (docs/placement.md).
3. a final control run of the finished design: round p. ``pcc_by_round`` is (p + 1, n_targets).
``result.placement["start_pcc"]``: each target's PCC against the (averaged) rest shape; a target below
0 (anti-correlated, a bad start) is listed in ``bad_start``.

Modules: ``settings`` (DesignSettings), ``initialize`` (checks, initial rest shape, design copies),
``placement`` (the paper's rule, candidate ends), ``refine`` (the simulated placement's refinement
rounds), ``greedy`` (the greedy placement),
``selection`` (which actuators each target's sequence leaves out), ``loop`` (design), ``result``
(DesignResult, plain data).
"""

from .initialize import copy_design, initial_rest_shape
from .loop import design
from .placement import PLACEMENTS, PlacementContext, paper_placement
from .result import DesignResult
from .selection import Selection, selection_from_settings, selection_to_settings
from .settings import PLACEMENT_METHODS, DesignSettings
from .greedy import greedy_placement
from .refine import refine_holds

__all__ = ["DesignSettings", "DesignResult", "design", "initial_rest_shape", "copy_design", "selection_to_settings",
           "selection_from_settings", "PlacementContext", "paper_placement", "PLACEMENTS", "Selection",
           "greedy_placement", "refine_holds", "PLACEMENT_METHODS"]
