"""The start of a design run: checked inputs, the initial rest shape, room for cells, and design copies."""

from __future__ import annotations

import math

import numpy as np

from ..display import Design
from ..errors import DesignError
from ..mesh import TriMesh
from ..controller.checks import target_labels
from ..controller.problem import Problem, as_problem
from ..targets import identifier_for, is_identifier

__all__ = ["check_request", "check_targets", "initial_rest_shape", "check_cell_room", "copy_design"]


def check_request(base, actuators) -> None:
    """A clear error unless ``base`` is a TriMesh and ``actuators`` a whole number >= 1."""
    if not isinstance(base, TriMesh):
        raise DesignError(f"base must be a ws.TriMesh (e.g. ws.icosphere(3, 0.035)), got {type(base).__name__}")
    if isinstance(actuators, bool) or not isinstance(actuators, (int, np.integer)) or actuators < 1:
        raise DesignError(f"actuators must be a whole number >= 1, got {actuators!r}")


def check_targets(targets, target_names, device: str = "cpu") -> Problem:
    """The run's problem: the targets centred on their volume centroids, and their names; errors for no
    target, a non-mesh, a wrong number of names, a duplicate name or the same shape given twice."""
    problem = Problem(targets, target_names, device=device, job="design")
    targets, names = problem.targets, problem.names
    if len(set(names)) != len(names):
        raise DesignError(f"duplicate target names {names}; give each target once")
    for n in names:
        if not is_identifier(n):
            raise DesignError(f"target name {n!r} is not an identifier (letters, digits, _; not starting with a "
                              f"digit): it becomes a USD prim name of the saved design; use e.g. {identifier_for(n)!r}")
    centred = targets
    problem.labels = tuple(target_labels(targets, names))
    for a in range(len(centred)):
        for b in range(a):
            ta, tb = centred[a], centred[b]
            if ta.vertices.shape == tb.vertices.shape and np.array_equal(ta.faces, tb.faces) \
                    and np.allclose(ta.vertices, tb.vertices, atol=1e-9):
                raise DesignError(f"duplicate targets: {names[a]} and {names[b]} are the same shape; give each once")
    return problem


def initial_rest_shape(base: TriMesh, targets, volume_scale: float = 0.8, device: str = "cpu") -> TriMesh:
    """Rest shape from the base mesh's directions: mean of volume-normalised sampled target radii,
    scaled to ``volume_scale`` x the smallest target volume. ``targets``: centred meshes or the run's
    ``Problem`` (its sampler is used)."""
    base = base.centered()
    dirs = base.vertices / np.linalg.norm(base.vertices, axis=1, keepdims=True)
    sampler = as_problem(targets, device=device, centre=False).sampler
    radii = []
    for j, t in enumerate(targets):
        hits = sampler.sample(dirs * 1e-3, j)
        radii.append(np.linalg.norm(hits, axis=1) / t.volume() ** (1.0 / 3.0))
    rest = base.copy_with(dirs * np.mean(radii, axis=0)[:, None])
    rest = TriMesh(rest.vertices, rest.faces)  # validate: averaging radii keeps a star-shaped, closed membrane
    scale = (volume_scale * min(t.volume() for t in targets) / rest.volume()) ** (1.0 / 3.0)
    return rest.scaled(scale)


def check_cell_room(rest: TriMesh, actuators: int, cell_radius: float) -> None:
    """A clear error when ``actuators`` sets of two cells of ``cell_radius`` cannot fit on ``rest``."""
    per_cell = max(1.0, math.pi * cell_radius**2 / float(np.mean(rest.face_areas())))
    if 2 * actuators * per_cell > rest.n_faces:
        need, radius_mm = f"{2 * actuators * per_cell:.0f}", f"{cell_radius * 1e3:.1f}"
        exc = DesignError(
            f"{actuators} actuators need about {need} faces of jamming cells (radius {radius_mm} mm) but the "
            f"membrane has {rest.n_faces}; use fewer actuators, a smaller cell_radius or a finer base mesh")
        # (faces needed, cell radius in mm, faces of the membrane) as printed, for front ends' advice
        exc.cell_room = (int(need), float(radius_mm), rest.n_faces)
        raise exc


def copy_design(d: Design, rest: TriMesh | None = None) -> Design:
    """A copy of ``d`` (with a new rest mesh where given): ``Design.replace``'s rule, every family, cell
    and flag kept."""
    return d.replace(rest=rest)
