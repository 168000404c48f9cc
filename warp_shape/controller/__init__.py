"""The controller: drive a design to target shapes (paper section IV-B, SPEC section 6).

``control`` / ``control_many`` run the control method ``ControlSettings.method`` (``CONTROL_METHODS``):
``"inverse"`` (default: the paper's law as warm start, then model-based control;
docs/inverse_control.md) or a control law alone (``LAWS``: ``"paper"``, eqs. 11-15;
docs/controller.md, with the readings of the paper's ambiguities). Several targets of one design
run as one batch of simulated worlds. ``register_law`` / ``register_control_method`` add strategies.

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
from .methods import CONTROL_METHODS, control, control_many, register_control_method, register_law, screen_many
from .observe import Observation, Observer
from .open_loop import replay
from .result import ControlResult, ScreenResult
from .control_settings import ControlSettings

__all__ = ["ControlSettings", "ControlResult", "ScreenResult", "control", "control_many", "screen_many", "cell_anchor_faces", "Controls",
           "LawStep", "PaperLaw", "LAWS", "CONTROL_METHODS", "register_control_method", "register_law", "Observation",
           "Observer", "HISTORY_COLUMNS", "replay"]
