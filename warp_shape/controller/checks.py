"""Targets checked against the device before any simulation, each failure an error that names the fix.

A target (centred on its volume centroid, as the controller and the designer use it) is compared with
the membrane's rest shape:
- size: the linear scale ratio s = (V_target / V_rest)^(1/3). A ratio near 1000 is a target given in
  millimetres (``UNITS_RATIO``), one near 100 in centimetres (``UNIT_MIXUPS``); a ratio beyond ``max_stretch`` asks for more mean stretch than the
  controller's stretch guard allows; a target of less volume than the rest shape would leave the
  membrane slack (it cannot shrink below its rest shape, only wrinkle): each is rejected.
- the sampled target: the target sampled radially through the rest shape's vertices, with the rest
  shape's triangles, must enclose a positive volume with every triangle facing outward (seen from the
  origin). Otherwise the rest shape does not surround the target's centre and radial sampling folds.
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError
from ..mesh import TriMesh
from ..sampling import RadialSampler

__all__ = ["UNITS_RATIO", "UNIT_MIXUPS", "check_target_units", "check_targets_against_rest", "target_labels"]

# Linear scale ratios (target / rest) read as a unit mix-up: millimetres given as metres.
UNITS_RATIO = (300.0, 3000.0)
#: every ratio range read as a unit mix-up: (low, high, the unit, its scale to metres, the command-line fix);
#: beyond the last the target is refused as far too large whatever its unit
UNIT_MIXUPS = ((30.0, UNITS_RATIO[0], "centimetres", "1e-2", "on the command line save the mesh file in metres "
                "or millimetres and give --units m or --units mm"),
               (*UNITS_RATIO, "millimetres", "1e-3", "on the command line a mesh file is read in millimetres with "
                "--units mm"))


def target_labels(targets, names) -> list[str]:
    """Labels for messages: "target <name>" (a name that already says "target" is kept as it is)."""
    names = list(names) if names is not None else [str(j) for j in range(len(targets))]
    return [n if str(n).startswith("target") else f"target {n}" for n in names]


def check_target_units(rest: TriMesh, targets, names=None, *, what: str = "rest shape") -> None:
    """Raise ``ShapeError`` for a target about 100x or 1000x the size of ``rest`` (given in centimetres or
    millimetres, ``UNIT_MIXUPS``) or larger still, naming the scale and the ``--units`` flag that fix it."""
    v_rest = rest.volume()
    for t, name in zip(targets, target_labels(targets, names)):
        s = (t.volume() / v_rest) ** (1.0 / 3.0)
        sizes = f"{name} is {s:.0f}x the size of the {what} (volume {t.volume():.3g} m^3 against {v_rest:.3g} m^3)"
        for low, high, unit_name, factor, cli in UNIT_MIXUPS:
            if low <= s <= high:
                raise ShapeError(f"{sizes}: it looks like {unit_name}: scale it by {factor} (target.scaled({factor}); "
                                 f"{cli}); warp_shape works in metres")
        if s > UNIT_MIXUPS[-1][1]:
            raise ShapeError(f"{sizes}: far too large for a display of that size in any unit (mm, cm, m); check the "
                             f"file's units and scale it to metres (target.scaled(...); on the command line a mesh "
                             f"file is read in millimetres with --units mm)")


def _check_size(rest: TriMesh, t: TriMesh, name: str, max_stretch: float) -> None:
    v_rest, v_t = rest.volume(), t.volume()
    if not (np.isfinite(v_t) and v_t > 0):
        raise ShapeError(f"{name} encloses a non-positive volume ({v_t:.3g} m^3): its faces are wound "
                         f"inward (inverted); reverse the winding (faces[:, ::-1])")
    s = (v_t / v_rest) ** (1.0 / 3.0)
    if s > max_stretch:
        raise ShapeError(
            f"{name} is {s:.2f}x the size of the rest shape (volume {v_t * 1e6:.4g} cm^3 against "
            f"{v_rest * 1e6:.4g} cm^3): the membrane would need a mean stretch of about {s:.2f}, beyond "
            f"max_stretch {max_stretch:g}; scale the target down, use a larger rest shape (or initialise it from "
            f"the targets: warp-shape design does; in Python ws.design(..., initialize=True)), or raise max_stretch")
    if v_t < v_rest:
        hint = (" (the rest shape is about 1000x the target: is the design in millimetres? scale it by 1e-3)"
                if 1.0 / UNITS_RATIO[1] <= s <= 1.0 / UNITS_RATIO[0] else "")
        raise ShapeError(
            f"{name} is smaller than the rest shape (volume {v_t * 1e6:.4g} cm^3 against "
            f"{v_rest * 1e6:.4g} cm^3): the membrane cannot shrink below its rest shape and would go slack"
            f"{hint}; initialise the rest shape from the targets (warp-shape design does; in Python "
            f"ws.design(..., initialize=True)) or use a smaller base")


def _check_sampled(rest: TriMesh, sampled: np.ndarray, name: str) -> None:
    """The target sampled through the rest vertices must enclose a positive volume, no face inverted."""
    p = sampled[rest.faces]  # (F, 3, 3)
    signed = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))  # 6 x each face's signed cone volume
    inverted = int(np.sum(signed <= 0))
    vol = float(signed.sum() / 6.0)
    if inverted or not vol > 0:
        raise ShapeError(
            f"{name} sampled through the rest shape's vertices encloses {vol:.3g} m^3 with {inverted} of "
            f"{len(signed)} faces inverted: the rest shape does not surround the target's centre (its volume "
            f"centroid, the origin) as a star, so the rays fold; centre the rest shape on the origin "
            f"(rest.centered()) and make it star-shaped from there")


def check_targets_against_rest(rest: TriMesh, targets, sampler: RadialSampler, names=None, *,
                               max_stretch: float) -> None:
    """Check centred ``targets`` (``sampler`` samples target j as its target j) against the membrane's
    ``rest`` shape before any simulation: units, size against the rest shape and ``max_stretch``, and
    the sampled target's volume and orientation. Raises ``ShapeError`` naming the problem and the fix."""
    names = target_labels(targets, names)
    check_target_units(rest, targets, names)
    for t, name in zip(targets, names):
        _check_size(rest, t, name, max_stretch)
    W = len(targets)
    sampled = sampler.sample_worlds(np.broadcast_to(rest.vertices, (W,) + rest.vertices.shape), np.arange(W))
    for j, name in enumerate(names):
        _check_sampled(rest, sampled[j], name)
