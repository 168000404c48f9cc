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
   achieved face centroid, r: its radius); the free face (no cell, no IPAM end) with the largest
   |e| over all targets is one IPAM end; the other end is, in that target, the free face with the
   largest error of the same sign among faces at least ``min_angle`` (120 degrees) away seen from
   the origin; add the IPAM and a jamming cell of ``cell_radius`` around each end (faces whose rest
   centroids lie within the radius and are in no cell yet).
3. a final control run of the finished design: round p. ``pcc_by_round`` is (p + 1, n_targets).

Actuator selection (``select_actuators``, on by default; not in the paper's algorithm): when a new
actuator set raises a target's fit objective (the controller's ``objective``) by more than the
relative tolerance ``max_rise`` (0.5 %), that target is re-run with the new set held neutral (IPAM
natural length tracking its length, cells never jammed: the paper notes in section V-C that an
actuator can be neutralised this way) and, where the target already leaves sets out, with every set
in use (sets that do not help alone may help together: a cube's corner IPAMs each raise the
objective under the paper's law, four together halve it); the run with the lowest objective is kept.
The control sequence then records which actuators each target uses; ``added[k]["left_out_for"]`` lists them.

Modules: ``settings`` (DesignSettings), ``initialize`` (checks, initial rest shape, design copies),
``placement`` (where the next actuator set goes: the paper's rule), ``selection`` (which actuators
each target's sequence leaves out), ``loop`` (design), ``result`` (DesignResult, plain data).
"""

from .initialize import copy_design, initial_rest_shape
from .loop import design
from .placement import PLACEMENTS, PlacementContext, paper_placement
from .result import DesignResult
from .selection import Selection, objective_selection, selection_from_settings, selection_to_settings
from .settings import DesignSettings

__all__ = ["DesignSettings", "DesignResult", "design", "initial_rest_shape", "copy_design", "selection_to_settings",
           "selection_from_settings", "PlacementContext", "paper_placement", "PLACEMENTS", "Selection",
           "objective_selection"]
