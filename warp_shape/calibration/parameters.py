"""The parameters a calibration fits: names, units, bounds, and a design built from their values.

Every parameter is positive and fitted as its logarithm (a step is a relative change), clipped to
its physical bounds. A fitted value applies to a design as ``apply_values``: the material's Young's
modulus, thickness and bending stiffness (the springs), shear modulus and Yeoh terms (the hyperelastic
membranes, docs/membrane.md), each IPAM's stiffness and area, and the rest-shape scale
(a uniform mold shrinkage or swelling about the rest centroid), and each region's multiplier of E t
(``region_stretch``, regions of ``calibration.regions``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..display import Design
from ..errors import DesignError
from .regions import face_scale

__all__ = ["CALIBRATION_PARAMETERS", "DEFAULT_WRT", "HYPERELASTIC_WRT", "BOUNDS", "Parameter", "ParameterSet",
           "apply_values", "check_wrt", "default_wrt", "check_law"]

#: the parameters ``calibrate`` fits, with their units
CALIBRATION_PARAMETERS = {
    "youngs_modulus": "Pa: the silicone's Young's modulus E (thickness held: only E t acts on the springs)",
    "thickness": "m: the load-bearing thickness t (springs: only E t acts, not separable from E; hyperelastic: "
                 "the sheet's t mu and the plate bending's t^3 mu, separable only through the bending)",
    "bending_stiffness": "N m/rad: the hinge bending stiffness k_t (springs only)",
    "shear_modulus": "Pa: the hyperelastic membrane's shear modulus mu (neo_hookean, yeoh; starts at E / 3 "
                     "where the design leaves it None)",
    "yeoh_c2": "Pa: the Yeoh law's C2 (yeoh only; must start > 0)",
    "yeoh_c3": "Pa: the Yeoh law's C3 (yeoh only; must start > 0)",
    "ipam_stiffness": "N/m, (n_ipam,): each IPAM's stiffness k",
    "ipam_area": "m^2, (n_ipam,): each IPAM's area A",
    "rest_scale": "1: the rest shape's scale about its centroid (mold shrinkage < 1)",
    "region_stretch": "1, (n_regions,): each region's multiplier of E t (calibrate's regions=: plug, "
                      "cell_boundaries, patches:N)",
}
#: what ``calibrate`` fits when ``wrt`` is not given (the springs; ``default_wrt`` gives each law's)
DEFAULT_WRT = ("youngs_modulus", "bending_stiffness", "ipam_stiffness", "ipam_area", "rest_scale")
#: what ``calibrate`` fits on a hyperelastic membrane when ``wrt`` is not given (its bending follows mu and t)
HYPERELASTIC_WRT = ("shear_modulus", "ipam_stiffness", "ipam_area", "rest_scale")
#: the parameters only the springs have, and those only the hyperelastic laws (Yeoh: also its terms)
_SPRINGS_ONLY = ("youngs_modulus", "bending_stiffness")
_HYPERELASTIC_ONLY = ("shear_modulus", "yeoh_c2", "yeoh_c3")
#: physical bounds (SI) of every parameter; a fit also stays within a factor ``RELATIVE_BOUND`` of its start
BOUNDS = {
    "youngs_modulus": (1.0e3, 1.0e8),
    "thickness": (1.0e-4, 2.0e-2),
    "bending_stiffness": (1.0e-8, 1.0e-1),
    "ipam_stiffness": (0.5, 5.0e3),
    "ipam_area": (1.0e-8, 1.0e-3),
    "rest_scale": (0.8, 1.25),
    "region_stretch": (0.1, 10.0),
    "shear_modulus": (3.0e2, 3.0e7),
    "yeoh_c2": (1.0, 1.0e7),
    "yeoh_c3": (1.0e-2, 1.0e7),
}
RELATIVE_BOUND = 10.0
_PER_IPAM = ("ipam_stiffness", "ipam_area")


def check_wrt(wrt) -> tuple:
    """The parameter names asked for, checked against ``CALIBRATION_PARAMETERS``."""
    names = (wrt,) if isinstance(wrt, str) else tuple(wrt)
    choices = ", ".join(CALIBRATION_PARAMETERS)
    if not names:
        raise DesignError(f"calibrate wrt: no parameter given; choose from {choices}")
    bad = [n for n in names if n not in CALIBRATION_PARAMETERS]
    if bad:
        raise DesignError(f"calibrate wrt: unknown parameter {bad[0]!r}; choose from {choices}")
    return tuple(dict.fromkeys(names))


def default_wrt(design: Design) -> tuple:
    """What ``calibrate`` fits on ``design`` when not told: ``DEFAULT_WRT`` on springs, ``HYPERELASTIC_WRT``
    on a hyperelastic membrane; the IPAMs' parameters left out of a design without IPAMs."""
    names = HYPERELASTIC_WRT if design.material.hyperelastic else DEFAULT_WRT
    return tuple(n for n in names if design.n_ipams or n not in _PER_IPAM)


def check_law(design: Design, names, what: str = "calibrate wrt") -> None:
    """Every name of ``names`` acts on ``design``'s membrane law: a springs parameter on a hyperelastic
    membrane, a hyperelastic one on springs or a Yeoh term on a neo-Hookean sheet is an error naming the fix."""
    law = design.material.membrane
    if design.material.hyperelastic:
        bad = [n for n in names if n in _SPRINGS_ONLY]
        if bad:
            fix = ("fit shear_modulus (mu; E only sets it where shear_modulus is None)" if bad[0] == "youngs_modulus"
                   else "the plate bending follows shear_modulus and thickness: fit those")
            raise DesignError(f"{what}: {bad[0]} does not act on the {law} membrane; {fix}")
    else:
        bad = [n for n in names if n in _HYPERELASTIC_ONLY]
        if bad:
            raise DesignError(f"{what}: {bad[0]} is a hyperelastic membrane's parameter and the design's "
                              f"membrane is springs; fit youngs_modulus, or design with membrane='neo_hookean'/'yeoh'")
    yeoh = [n for n in names if n in ("yeoh_c2", "yeoh_c3")]
    if yeoh and law != "yeoh":
        raise DesignError(f"{what}: {yeoh[0]} is a Yeoh term and the design's membrane is {law}; "
                          f"use membrane='yeoh' with a starting {yeoh[0]} > 0")


@dataclass(frozen=True)
class Parameter:
    """One fitted scalar: ``name`` (a key of ``CALIBRATION_PARAMETERS``), ``index`` (the IPAM, or None),
    its start value and bounds (SI)."""

    name: str
    index: int | None
    start: float
    lower: float
    upper: float
    tag: str | None = None  # a region's name

    @property
    def label(self) -> str:
        """``name``, ``name[index]`` or ``name[region]``."""
        return self.name if self.index is None else f"{self.name}[{self.tag if self.tag else self.index}]"


def design_value(design: Design, name: str, index: int | None) -> float:
    """The value of parameter ``name`` (IPAM ``index``) in ``design``."""
    if name in ("rest_scale", "region_stretch"):
        return 1.0
    if name in _PER_IPAM:
        ip = design.ipams[index]
        return ip.stiffness if name == "ipam_stiffness" else ip.area
    if name == "shear_modulus":
        return float(design.material.mu)  # None in the design: E / 3, the mu in effect
    return float(getattr(design.material, name))


class ParameterSet:
    """The scalars fitted for ``wrt`` on ``design``, as a vector of logarithms; ``regions`` ({name: faces},
    ``calibration.regions.region_faces``) those of ``region_stretch``."""

    def __init__(self, design: Design, wrt, regions: dict | None = None):
        names = check_wrt(wrt)
        check_law(design, names)
        self.regions = dict(regions or {})
        if any(n in _PER_IPAM for n in names) and not design.n_ipams:
            raise DesignError("calibrate wrt: the design has no IPAMs; leave ipam_stiffness and ipam_area out")
        if "region_stretch" in names and not self.regions:
            raise DesignError("calibrate wrt: region_stretch is fitted per region; give regions= (plug, "
                              "cell_boundaries, patches:N)")
        if self.regions and "region_stretch" not in names:
            raise DesignError("calibrate: regions given but region_stretch is not in wrt; add it")
        tags = list(self.regions)
        params = []
        for name in names:
            count = design.n_ipams if name in _PER_IPAM else len(tags) if name == "region_stretch" else None
            for index in (range(count) if count is not None else [None]):
                v = design_value(design, name, index)
                if not v > 0:
                    raise DesignError(f"calibrate wrt: {name} is {v!r} in the design; a fitted parameter must start "
                                      f"> 0 (set it in the design's material, or leave it out of wrt)")
                lo, hi = BOUNDS[name]
                lo, hi = max(lo, v / RELATIVE_BOUND), min(hi, v * RELATIVE_BOUND)
                if not lo <= v <= hi:
                    raise DesignError(f"calibrate: {name} = {v:g} lies outside its physical bounds "
                                      f"[{BOUNDS[name][0]:g}, {BOUNDS[name][1]:g}]")
                params.append(Parameter(name, index, v, lo, hi, tags[index] if name == "region_stretch" else None))
        self.names = names
        self.params = params
        self.lower = np.log([p.lower for p in params])
        self.upper = np.log([p.upper for p in params])
        self.x0 = np.log([p.start for p in params])

    def __len__(self) -> int:
        return len(self.params)

    @property
    def labels(self) -> list[str]:
        """``name`` or ``name[i]`` of every scalar."""
        return [p.label for p in self.params]

    def clip(self, x: np.ndarray) -> np.ndarray:
        """``x`` held within the bounds."""
        return np.clip(x, self.lower, self.upper)

    def values(self, x: np.ndarray) -> dict:
        """{name: float or (n_ipam,) array} of the vector ``x`` (SI)."""
        out = {}
        for p, v in zip(self.params, np.exp(x)):
            if p.index is None:
                out[p.name] = float(v)
            else:
                out.setdefault(p.name, np.zeros(0))
                out[p.name] = np.append(out[p.name], v)
        return out

    def per_name(self, vector: np.ndarray) -> dict:
        """{name: float or array} of any per-scalar vector (standard errors, bounds)."""
        out = {}
        for p, v in zip(self.params, vector):
            out[p.name] = float(v) if p.index is None else np.append(out.get(p.name, np.zeros(0)), v)
        return out

    def design(self, design: Design, x: np.ndarray) -> Design:
        """``design`` with the values of ``x``."""
        return apply_values(design, self.values(x), regions=self.regions)


def apply_values(design: Design, values: dict, regions: dict | None = None) -> Design:
    """A copy of ``design`` with calibrated ``values`` ({name: value}, SI; see ``CALIBRATION_PARAMETERS``):
    material fields replaced, IPAM stiffness and area replaced (per IPAM), the rest shape scaled about its
    centroid by ``rest_scale`` (an IPAM whose free length is its rest length keeps following it; another's
    free length scales with it), E t multiplied on each region's faces by ``region_stretch`` (``regions``
    {name: faces} in the values' order). Cells keep their faces; other actuator families are copied unchanged."""
    unknown = sorted(set(values) - set(CALIBRATION_PARAMETERS))
    if unknown:
        raise DesignError(f"unknown calibration parameter {unknown[0]!r}; known: {', '.join(CALIBRATION_PARAMETERS)}")
    check_law(design, tuple(values), "calibration values (a calibration of another membrane law: give the design "
                                     "that law, --membrane)")
    mat = replace(design.material, **{k: float(values[k]) for k in ("youngs_modulus", "thickness", "bending_stiffness",
                                                                      *_HYPERELASTIC_ONLY) if k in values})
    scale = float(values.get("rest_scale", 1.0))
    if not (math.isfinite(scale) and scale > 0):
        raise DesignError(f"rest_scale must be a positive number, got {scale!r}")
    rest = design.rest
    if scale != 1.0:
        c = rest.centroid()
        rest = rest.copy_with(c + scale * (rest.vertices - c))
    n = design.n_ipams
    k = _per_ipam(values, "ipam_stiffness", [ip.stiffness for ip in design.ipams], n)
    a = _per_ipam(values, "ipam_area", [ip.area for ip in design.ipams], n)
    ipams = [replace(ip, stiffness=float(k[i]), area=float(a[i]),
                     free_length=ip.free_length if ip.free_length_is_rest else ip.free_length * scale)
             for i, ip in enumerate(design.ipams)]
    stretch = False  # kept
    if "region_stretch" in values:
        if not regions:
            raise DesignError("region_stretch values need their regions (face indices): a calibration file "
                              "without them is damaged; calibrate again")
        stretch = face_scale(design, regions, values["region_stretch"])
    out = design.replace(rest=rest, material=mat, ipams=ipams, stretch_scale=stretch)
    return out


def _per_ipam(values: dict, name: str, default, n: int) -> np.ndarray:
    if name not in values:
        return np.asarray(default, dtype=np.float64)
    v = np.asarray(values[name], dtype=np.float64).reshape(-1)
    if v.size == 1 and n != 1:
        v = np.full(n, float(v[0]))
    if v.size != n:
        raise DesignError(f"{name} has {v.size} values but the design has {n} IPAMs: a calibration of another design")
    if not np.all(np.isfinite(v) & (v > 0)):
        raise DesignError(f"{name} values must be positive numbers (SI), got {v.tolist()}")
    return v
