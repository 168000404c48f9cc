"""The controller: drive a design to target shapes (paper section IV-B, SPEC section 6).

Every control period (several simulation steps) the controller samples each target radially at the
membrane's vertices, then updates
- the chamber air by eq. (11): dn = (V_t - V) p_abs / (R T), V_t the volume of the sampled target;
- each IPAM by eq. (12): dP = (k / A) (L_t - L), L_t the distance between the centroids of the IPAM's
  end faces on the sampled target;
- each jamming cell by eqs. (13)-(15): curvature kappa = r_end - mean r over the cell's faces (radius
  of a face = |centroid|); a cell jams the first control step its curvature moves away from its
  target (it is not between its value at the previous shape-control step and the target), once,
  never released; no cell jams at the first shape-control step.
Phase 1 (initial inflation) actuates only the air until the volume is in its deadband. Increments
are rate limited. A run ends when volume and every IPAM length are in their deadbands (an IPAM
pinned at a pressure limit while its target asks for more counting as in: it cannot move), when the
membrane stretches beyond ``max_stretch``, or at the step limit; the controls are then held until
the membrane is at rest (largest vertex speed below ``settle_speed``, at most ``max_settle_steps``)
and everything reported is measured there. ``converged``: at rest, within the deadbands, nothing
saturated; ``saturated`` names the actuators pinned at a limit; ``reason`` says why it ended. The fit
is judged by one objective (area-weighted RMS of (R - r) / V_t^(1/3)), with PCC, MARE and MPRE
beside it. Eqs. (11)-(12) are deadbeat laws that assume the membrane settles within a control period;
where it does not (coarse, lightly damped membranes), an error that flips sign without halving
halves that world's (or IPAM's) gain, down to ``min_gain`` (``gain_backoff``; not in the paper).
Targets are checked against the device before any simulation (``checks``). docs/controller.md lists
the readings of the paper's ambiguities.

Several targets of one design run as one batch of simulated worlds (one launch per kernel for all).

``method="inverse"`` (the default) takes the paper's law above as its warm start, then controls the
air, the IPAM pressures and the jamming plan on the fit objective with the settled shape's
finite-difference Jacobian from batched worlds (``inverse``; docs/inverse_control.md).
``method="paper"`` is the paper's law alone.

Modules: ``settings`` (ControlSettings), ``checks`` (targets against the device), ``observe`` (one
observation of every world), ``laws`` (control laws as strategies: the paper's), ``history`` (the
per-step record, its columns documented there), ``loop`` (the law loop), ``methods`` (control methods
as strategies, ``control`` / ``control_many``), ``result``
(ControlResult, plain data); model-based control: ``inverse`` (the driver), ``plans`` (jam plans),
``trajectory`` (the recorded main sequence of a plan), ``explore`` (scratch batches of worlds),
``refine`` (Gauss-Newton iterations), ``gauss_newton`` (the bounded damped step), ``worlds`` (passive
masks and speeds per world), ``replay`` (a recorded sequence re-simulated open loop).
"""

from ..model import cell_anchor_faces
from .history import HISTORY_COLUMNS
from .laws import LAWS, Controls, LawStep, PaperLaw
from .methods import CONTROL_METHODS, control, control_many, register_control_method, register_law
from .observe import Observation, Observer
from .replay import replay
from .result import ControlResult
from .settings import ControlSettings

__all__ = ["ControlSettings", "ControlResult", "control", "control_many", "cell_anchor_faces", "Controls",
           "LawStep", "PaperLaw", "LAWS", "CONTROL_METHODS", "register_control_method", "register_law", "Observation",
           "Observer", "HISTORY_COLUMNS", "replay"]
