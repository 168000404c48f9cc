"""warp_shape: simulator and automatic design tool for soft 3-D haptic shape displays.

Quick start::

    import warp_shape as ws
    d = ws.Design(rest=ws.icosphere(3, 0.04), material=ws.Material())
    sim = ws.Simulator(d, device="cpu")
    sim.air_moles *= 1.05
    sim.step(100)

Importing the package lowers Warp's log level to warnings (no start-up banner, no line per kernel
module loaded), unless it was changed before; ``warp.config.log_level = warp.LOG_INFO`` shows them.
"""

from .interrupts import hold_for_the_command

hold_for_the_command()  # the warp-shape command only: Ctrl-C while it starts is answered by its main()

from .force_family import ACTUATOR_FAMILIES, FORCE_FAMILIES, ActuatorFamily, ForceFamily
from .calibration import CalibrationResult, ControlState, ScanObservation, calibrate
from .calibration.files import apply_calibration, read_calibration, write_calibration
from .controller import (CONTROL_METHODS, LAWS, ControlResult, ControlSettings, control, control_many,
                         register_control_method, register_law, replay)
from .display import Cell, Design, Ipam
from .feel import Press, StiffnessGradient, press, stiffness_gradient, stiffness_map
from .designer import PLACEMENTS, DesignResult, DesignSettings, Placement, design, register_placement
from .gradients import GRADIENT_PARAMETERS, Gradient, gradient
from .errors import DesignError, MeshError, SceneError, ShapeError, SimulationError, StabilityError, WarpShapeError
from .io.figures import control_figure, pcc_by_round_figure, write_figures
from .io.recorder import Recorder
from .io.recording_read import read_recording
from .io.scene_read import load_scene, validate_usd
from .io.scene_registry import list_scenes
from .io.scene_schema import Scene
from .io.scene_write import save_scene
from .io.usd_animation import export_animation
from .material import GAS_CONSTANT, Material
from .mesh import TriMesh, icosphere
from .sampling import (RadialSampler, check_star_shaped, fibonacci_directions, mare, mpre, pcc, radial_metrics,
                       radial_sample, shape_metrics)
from .scan import ScanComparison, compare_scan, load_scan
from .simulation_settings import SimulationSettings
from .simulator import Simulator
from .sweeps import sweep  # the package is warp_shape.sweeps; ws.sweep(...) is its function
from .physics import FORCE_TERMS
from .targets import DEFAULT_VOLUME, TARGET_NAMES, target

__version__ = "0.1.0"


import warp as _warp  # noqa: E402

if _warp.config.log_level == _warp.LOG_INFO:  # Warp's default: a line per module loaded
    _warp.config.log_level = _warp.LOG_WARNING
