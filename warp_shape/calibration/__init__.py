"""Calibration from scans: fit a design's material and IPAM parameters to scans of the built device
(docs/calibration.md). Files (manifests, calibration files, residual figures): ``calibration.files``."""

from .fit import calibrate, scan_residuals
from .observations import ControlState, ScanObservation, Sequence
from .parameters import BOUNDS, CALIBRATION_PARAMETERS, DEFAULT_WRT, HYPERELASTIC_WRT, apply_values, default_wrt
from .held_replay import HOLD_S, replay_held
from .result import CalibrationResult, ScanResidual

__all__ = ["calibrate", "scan_residuals", "ControlState", "ScanObservation", "Sequence", "BOUNDS",
           "CALIBRATION_PARAMETERS", "DEFAULT_WRT", "HYPERELASTIC_WRT", "default_wrt", "apply_values", "HOLD_S",
           "replay_held", "CalibrationResult", "ScanResidual"]
