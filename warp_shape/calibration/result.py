"""CalibrationResult: fitted values, standard errors, the calibrated design and the residual maps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..display import Design

__all__ = ["CalibrationResult", "ScanResidual"]


@dataclass
class ScanResidual:
    """One observation after the fit: ``points`` (N, 3) the scan points used, aligned to the model
    (m, model frame), ``residual`` (N,) signed point-to-surface distance (m, + outside), ``weight`` (N,)
    the robust loss's weight (0: rejected as an outlier), ``transform`` 4x4 scan -> model, ``vertices``
    (V, 3) the replayed membrane (m), ``vertex_residual`` (V,) the mean signed residual of the scan points
    nearest each vertex (m, NaN where none)."""

    name: str
    points: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    weight: np.ndarray = field(repr=False)
    transform: np.ndarray = field(repr=False)
    vertices: np.ndarray = field(repr=False)
    vertex_residual: np.ndarray = field(repr=False)

    @property
    def rms_mm(self) -> float:
        """RMS of the residuals of the points kept (weight > 0), mm."""
        keep = self.weight > 0
        return float(np.sqrt(np.mean(self.residual[keep] ** 2)) * 1e3) if keep.any() else float("nan")


@dataclass
class CalibrationResult:
    """Outcome of ``ws.calibrate`` (SI units).

    ``values`` / ``stderr``: {name: float or (n_ipams,) array} fitted values and their standard errors
    (inf where the observations do not determine it); ``start``: the values before the fit;
    ``design``: the calibrated design; ``residual_mm``: per observation the RMS residual after the fit
    (mm) and ``initial_residual_mm`` before it; ``unidentifiable``: names of the parameters or
    combinations the observations cannot separate (e.g. ``"youngs_modulus ~ thickness"``, ``"ipam_area[4]"``)
    with ``notes`` saying why; ``residuals``: the per-scan residual maps (``ScanResidual``);
    ``labels`` the fitted scalars, ``correlation`` their correlation matrix; ``iterations``,
    ``jacobians`` (finite-difference Jacobians computed), ``converged``, ``costs`` (robust cost per iteration);
    ``regions`` {name: rest face indices} of ``region_stretch`` (labelled ``region_stretch[name]``);
    ``poorly_determined``: the identifiable combinations whose standard error exceeds 5 %, each with
    its members and what would fix it (e.g. the stiffnesses' common scale without pressure readings).

    What the fit can stand behind (docs/calibration.md, *What a calibration flags*): ``noise_mm`` the
    scans' point noise (the stated one, else estimated from the scatter about each vertex's mean
    residual), ``model_error_mm`` the RMS of the residual that is not noise (smooth over the membrane:
    what the model cannot follow), ``error_scale`` the factor the standard errors were multiplied by
    for it (1: none); ``z`` {label: |log change| / its standard error}; ``flags``: one line per
    parameter moved by more than ``FLAG_Z`` standard errors or stopped at a bound, and where the
    model error exceeds the noise; ``held_out`` per held-out scan (name, RMS residual on the start
    model, on the calibrated model; mm)."""

    values: dict
    stderr: dict
    start: dict
    design: Design = field(repr=False)
    residual_mm: list
    initial_residual_mm: list
    unidentifiable: list
    notes: list = field(default_factory=list)
    residuals: list = field(default_factory=list, repr=False)
    labels: list = field(default_factory=list)
    correlation: np.ndarray | None = field(default=None, repr=False)
    iterations: int = 0
    jacobians: int = 0
    converged: bool = False
    costs: list = field(default_factory=list)
    wrt: tuple = ()
    observation_names: list = field(default_factory=list)
    regions: dict = field(default_factory=dict, repr=False)  # {name: (n,) rest faces} of region_stretch
    poorly_determined: list = field(default_factory=list)  # directions known only to > 5 %, with the remedy
    realigned: list = field(default_factory=list)  # scans whose pose a first fit had in a wrong turn
    noise_mm: float = float("nan")
    model_error_mm: float = float("nan")
    error_scale: float = 1.0
    z: dict = field(default_factory=dict)
    flags: list = field(default_factory=list)
    held_out: list = field(default_factory=list)  # [(name, rms before mm, rms after mm)]

    def flagged(self, label: str) -> bool:
        """Whether a fitted scalar (``labels``) is named by a flag."""
        return any(f.startswith(label + " ") for f in self.flags)

    def relative_change(self) -> dict:
        """{name: value / start - 1}."""
        return {k: np.asarray(v) / np.asarray(self.start[k]) - 1.0 for k, v in self.values.items()}

    def summary(self) -> dict:
        """A JSON-ready dict of the values, standard errors and residuals."""
        def plain(v):
            a = np.asarray(v, dtype=np.float64)
            return [None if not np.isfinite(x) else float(x) for x in a.reshape(-1)] if a.ndim else \
                (None if not np.isfinite(a) else float(a))
        return dict(values={k: plain(v) for k, v in self.values.items()},
                    stderr={k: plain(v) for k, v in self.stderr.items()},
                    start={k: plain(v) for k, v in self.start.items()},
                    residual_mm=[float(x) for x in self.residual_mm],
                    initial_residual_mm=[float(x) for x in self.initial_residual_mm],
                    unidentifiable=list(self.unidentifiable), notes=list(self.notes),
                    poorly_determined=list(self.poorly_determined), realigned=list(self.realigned),
                    iterations=self.iterations, jacobians=self.jacobians, converged=self.converged,
                    noise_mm=self.noise_mm, model_error_mm=self.model_error_mm, error_scale=self.error_scale,
                    z={k: plain(v) for k, v in self.z.items()}, flags=list(self.flags),
                    held_out=[dict(scan=n, before_mm=a, after_mm=b) for n, a, b in self.held_out],
                    observations=list(self.observation_names))
