"""Swept parameters: which setting a name means, its values parsed and checked before a sweep starts.

A parameter is any field of ``DesignSettings`` (designer), ``ControlSettings`` (controller),
``SimulationSettings`` (simulation) or ``Material`` (material), any extra keyword option of
``designer.design``, ``actuators`` (the number of IPAMs) or ``subdivisions`` (the base mesh
resolution: an icosphere of that many subdivisions and the base mesh's mean radius). The settings
are read from the dataclasses at run time, so a setting added to one of them can be swept at once.
A name may be qualified (``controller.max_steps``) and must be where it is ambiguous.
"""

from __future__ import annotations

import difflib
import inspect
import math
import numbers
from dataclasses import MISSING, dataclass, fields

from ..controller import ControlSettings
from ..designer import DesignSettings, design
from ..errors import WarpShapeError
from ..limits import (MAX_ACTUATORS, MAX_CANDIDATES, MAX_CONTROL_PERIOD, MAX_CONTROL_STEPS, MAX_INVERSE_ITERATIONS,
                      MAX_REFINE_ROUNDS, MAX_SUBDIVISIONS, MAX_SUBSTEPS)
from ..material import Material
from ..simulation_settings import SimulationSettings

__all__ = ["SweepError", "Param", "GROUPS", "SPECIAL", "SIZE_BOUNDS", "known_params", "resolve_param", "parse_param",
           "parse_value", "check_values", "split_params"]

#: design() keywords that are not settings (the problem itself, callbacks, the settings objects)
_NOT_SETTINGS = {"base", "targets", "actuators", "device", "target_names", "settings", "control_settings",
                 "material", "progress", "on_round", "recorder", "overrides"}

#: settings groups: name -> dataclass
GROUPS = {"designer": DesignSettings, "controller": ControlSettings, "simulation": SimulationSettings,
          "material": Material}

#: parameters that are not a settings field: name -> (type, meaning)
SPECIAL = {"actuators": (int, "number of IPAMs placed"),
           "subdivisions": (int, f"base mesh: an icosphere of 1..{MAX_SUBDIVISIONS} subdivisions (2: 162 vertices, "
                                 f"3: 642)")}

#: the settings that size a run (counts, resolutions, steps), held before any work to the bounds of the
#: flag that gives them to one run (`warp-shape design` / `control`), or (no flag) to the foundation's
#: bounds: (group, field) -> (low, high, flag or None)
SIZE_BOUNDS = {
    ("run", "actuators"): (1, MAX_ACTUATORS, "--actuators"),
    ("run", "subdivisions"): (1, MAX_SUBDIVISIONS, "--subdivisions"),
    ("designer", "candidates"): (1, MAX_CANDIDATES, "--candidates"),
    ("designer", "refine_rounds"): (0, MAX_REFINE_ROUNDS, "--refine-rounds"),
    ("controller", "max_steps"): (1, MAX_CONTROL_STEPS, "--max-steps"),
    ("controller", "max_settle_steps"): (0, MAX_CONTROL_STEPS, None),
    ("controller", "inverse_settle_steps"): (1, MAX_CONTROL_STEPS, None),
    ("controller", "control_period"): (1, MAX_CONTROL_PERIOD, None),
    ("controller", "inverse_iterations"): (0, MAX_INVERSE_ITERATIONS, None),
    ("simulation", "substeps"): (1, MAX_SUBSTEPS, None),
    ("simulation", "max_substeps"): (1, MAX_SUBSTEPS, None),
}


#: names that look like settings but change no design or fit: name -> what they are instead
NOT_SWEPT = {name: f"{name} is a mold length (warp-shape design/export --{name.replace('_', '-')}, m), not a design "
                   f"setting: it changes no design and no fit, so a sweep has nothing to compare; give it to "
                   f"`warp-shape export runs/<run>/design.usda --{name.replace('_', '-')} VALUE` for the molds"
             for name in ("layer_thickness", "marker_height")}


class SweepError(WarpShapeError, ValueError):
    """A sweep cannot run as asked: an unknown parameter or value, a missing engine, a clashing output folder."""


@dataclass(frozen=True)
class Param:
    """One swept parameter: its ``group`` ("designer", "controller", "simulation", "material",
    "design" for a keyword option of ``designer.design``, or "run" for ``actuators`` / ``subdivisions``),
    its field ``name``, the type of its default and its values."""

    group: str
    name: str
    kind: type
    values: tuple = ()


def _design_keywords() -> dict:
    """Keyword options of ``designer.design`` beyond the settings objects (e.g. a placement method)."""
    out = {}
    for p in inspect.signature(design).parameters.values():
        if p.name in _NOT_SETTINGS or p.kind in (p.VAR_KEYWORD, p.VAR_POSITIONAL):
            continue
        out[p.name] = type(p.default) if p.default not in (inspect.Parameter.empty, None) else str
    return out


def known_params() -> dict:
    """Every sweepable name -> [(group, type)], unqualified; a name in two groups lists both."""
    out: dict = {name: [("run", kind)] for name, (kind, _) in SPECIAL.items()}
    for group, cls in GROUPS.items():
        for f in fields(cls):
            if f.name == "simulation" or f.name in SPECIAL:
                continue
            default = f.default if f.default is not MISSING else None
            kind = type(default) if default is not None else str
            out.setdefault(f.name, []).append((group, kind))
    for name, kind in _design_keywords().items():
        out.setdefault(name, []).append(("design", kind))
    return out


def resolve_param(name: str) -> tuple[str, str, type]:
    """(group, field, type) of a parameter name, plain or qualified (``material.youngs_modulus``);
    an unknown or ambiguous name raises ``SweepError`` with the closest names."""
    known = known_params()
    group, _, field_name = name.rpartition(".")
    if field_name in NOT_SWEPT and field_name not in known:
        raise SweepError(NOT_SWEPT[field_name])
    choices = known.get(field_name, [])
    if group:
        choices = [c for c in choices if c[0] == group]
    if not choices:
        qualified = [f"{g}.{n}" for n, gs in known.items() for g, _ in gs]
        close = difflib.get_close_matches(name, list(known) + qualified, n=4, cutoff=0.6)
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        raise SweepError(f"unknown sweep parameter {name!r}{hint} Sweepable: {', '.join(sorted(known))} "
                         f"(any designer, controller, simulation or material setting; qualify as group.name)")
    if len(choices) > 1:
        raise SweepError(f"sweep parameter {name!r} is a setting of {[g for g, _ in choices]}: qualify it, "
                         f"e.g. {choices[0][0]}.{field_name}")
    return choices[0][0], field_name, choices[0][1]


def parse_value(text, kind: type):
    """A value given on the command line (or in Python) as the setting's type."""
    if not isinstance(text, str):
        return text
    t = text.strip()
    if kind is bool:
        if t.lower() in ("1", "true", "yes", "on"):
            return True
        if t.lower() in ("0", "false", "no", "off"):
            return False
        raise SweepError(f"{text!r} is not a true/false value")
    if kind is int:
        try:
            return int(t)
        except ValueError:
            raise SweepError(f"{text!r} is not an integer") from None
    if kind is float:
        try:
            return float(t)
        except ValueError:
            raise SweepError(f"{text!r} is not a number") from None
    if kind is tuple:
        return tuple(float(v) for v in t.replace(";", " ").split())
    if kind is str and t.lower() == "none":
        return None
    if kind is str:  # a field whose default is None (e.g. substeps): a number where it reads as one
        for conv in (int, float):
            try:
                return conv(t)
            except ValueError:
                pass
    return t


def _check_size(group: str, field_name: str, value) -> None:
    """A size (``SIZE_BOUNDS``) within its bounds, as its flag's: a one-line ``SweepError`` naming them."""
    bounds = SIZE_BOUNDS.get((group, field_name))
    if bounds is None or value is None or isinstance(value, bool) or not isinstance(value, numbers.Real):
        return  # not a size, or not a number: the settings object's own checks say what it needs
    lo, hi, flag = bounds
    if not (math.isfinite(value) and lo <= value <= hi):
        where = field_name if group == "run" else f"{group}.{field_name}"
        same = f", as {flag} does" if flag else ""
        got = value if isinstance(value, numbers.Integral) else f"{value:g}"
        raise SweepError(f"sweep setting {where} takes {lo}..{hi}{same}, got {got}; give values within these "
                         f"bounds")


def _check_one(group: str, field_name: str, value) -> None:
    """Build the settings object with the value (its own checks run); a bad value raises ``SweepError``."""
    _check_size(group, field_name, value)
    try:
        if group == "run":
            if not isinstance(value, int) or isinstance(value, bool):
                raise SweepError(f"must be a whole number, got {value!r}")
            return
        if group == "design":
            return  # checked by design() when it runs
        cls = GROUPS[group]
        if group == "controller":
            ControlSettings().replace(**{field_name: value})
        else:
            cls(**{field_name: value})
    except (WarpShapeError, TypeError) as exc:
        where = field_name if group == "run" else f"{group}.{field_name}"
        raise SweepError(f"bad value {value!r} for sweep parameter {where}: {exc}") from None


def parse_param(spec: str) -> Param:
    """``NAME=v1,v2,...`` -> a checked ``Param`` (values parsed to the setting's type, each checked)."""
    name, sep, values = str(spec).partition("=")
    if not sep or not name.strip() or not values.strip():
        raise SweepError(f"--param needs NAME=VALUE1,VALUE2,... (e.g. actuators=5,10,20), got {spec!r}")
    return check_values(name.strip(), [v for v in values.split(",") if v.strip()])


def check_values(name: str, values) -> Param:
    """A ``Param`` from a name and a list of values (strings are parsed), every value checked."""
    group, field_name, kind = resolve_param(name)
    parsed = []
    for v in values:
        try:
            value = parse_value(v, kind)
        except SweepError as exc:
            raise SweepError(f"sweep parameter {name}: {exc}") from None
        _check_one(group, field_name, value)
        parsed.append(value)
    if not parsed:
        raise SweepError(f"sweep parameter {name} has no values")
    if len(set(map(repr, parsed))) != len(parsed):
        raise SweepError(f"sweep parameter {name} repeats a value: {list(values)}")
    return Param(group, field_name, kind, tuple(parsed))


def split_params(values: dict) -> dict:
    """{qualified or plain name: value} -> {group: {field: value}} (names resolved, unchecked values)."""
    out: dict = {g: {} for g in ("run", "design", *GROUPS)}
    for name, value in values.items():
        group, field_name, _ = resolve_param(name)
        out[group][field_name] = value
    return out
