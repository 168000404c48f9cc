"""The controller: drive a design to target shapes (paper section IV-B, SPEC section 6).

Every control period (several simulation steps) the controller samples each target radially at the
membrane's vertices, then updates
- the chamber air by eq. (11): dn = (V_t - V) p_abs / (R T), V_t the volume of the sampled target;
- each IPAM by eq. (12): dP = (k / A) (L_t - L), L_t the distance between the centroids of the IPAM's
  end faces on the sampled target;
- each jamming cell by eqs. (13)-(15): curvature kappa = r_end - mean r over the cell's faces (radius
  of a face = |centroid|); a cell jams the first control step its curvature moves away from its
  target (it is not between the previous value and the target), once, never released.
Phase 1 (initial inflation) actuates only the air until the volume is in its deadband. Increments
are rate limited; the run stops when volume and every IPAM length are in their deadbands, or at the
step limit (``converged`` False, with the reason). An IPAM pinned at a pressure limit while its
target asks for more counts as settled: it cannot do better. Eqs. (11)-(12) are deadbeat laws that
assume the membrane settles within a control period; where it does not (coarse, lightly damped
membranes), an error that flips sign without halving halves that world's (or IPAM's) gain, down
to ``min_gain`` (``gain_backoff``; not in the paper).

Several targets of one design run as one batch of simulated worlds (one launch per kernel for all).

``method="inverse"`` (the default) takes the paper's law above as its warm start, then controls the
air, the IPAM pressures and the jamming plan on the fit objective with the settled shape's
finite-difference Jacobian from batched worlds (``inverse``; docs/inverse_control.md).
``method="paper"`` is the paper's law alone.

Modules: ``settings`` (ControlSettings), ``observe`` (one observation of every world), ``laws``
(control laws as strategies: the paper's), ``history`` (the per-step record, its columns
documented there), ``loop`` (control / control_many), ``result`` (ControlResult, plain data);
model-based control: ``inverse`` (the driver), ``plans`` (jam plans), ``trajectory`` (the recorded
main sequence of a plan), ``explore`` (scratch batches of worlds), ``refine`` (Gauss-Newton
iterations), ``gauss_newton`` (the bounded damped step), ``worlds`` (world states as host data),
``replay`` (a recorded sequence re-simulated open loop).
"""

from .history import HISTORY_COLUMNS
from .laws import LAWS, Controls, LawStep, PaperLaw
from .loop import control, control_many
from .observe import DeviceConstants, Observation, Observer, cell_anchor_faces
from .replay import replay
from .result import ControlResult
from .settings import ControlSettings

__all__ = ["ControlSettings", "ControlResult", "control", "control_many", "cell_anchor_faces", "Controls",
           "LawStep", "PaperLaw", "LAWS", "DeviceConstants", "Observation", "Observer", "HISTORY_COLUMNS", "replay"]
