"""The problem of one run, built once: its targets centred, their names, volumes and radial sampler,
and the checks against the device done once.

A ``Problem`` is what the controller, the designer's loop and placements, co-design and the
results share: ``control_many(design, problem)`` neither centres its targets again nor builds a
second sampler nor repeats a check already passed. It is a sequence of its worlds' target meshes (a
control method's ``run`` reads it as a list of centred targets); ``take(indices)`` gives the
problem of some of its targets (repeats allowed, e.g. one world per candidate and target), sharing
the sampler (``RadialSampler.subset``) and the record of checks. Sent to a worker process, a
problem carries its targets and that record; the worker builds the sampler once for every job of
the run (``SAMPLERS``, by the problem's token), without repeating the star-shape check.
"""

from __future__ import annotations

import itertools
import os
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from ..errors import DesignError
from ..mesh import TriMesh
from ..sampling import RadialSampler
from ..targets import centred_targets
from . import checks

__all__ = ["Problem", "as_problem", "take", "SAMPLERS"]

#: per process: the samplers of the problems seen last, by (token, device); a worker keeps the one of its run
SAMPLERS: "OrderedDict[tuple, RadialSampler]" = OrderedDict()
_KEEP = 4  # problems whose samplers a process keeps
_TOKENS = itertools.count()


def _rest_key(rest: TriMesh, max_stretch: float) -> tuple:
    return (rest.vertices.tobytes(), rest.faces.tobytes(), float(max_stretch))


class Problem(Sequence):
    """Targets (centred on their volume centroids unless ``centre`` is False: already centred), their
    ``names`` (default ``target<j>``) and ``labels`` for messages, on ``device``; ``job`` names the
    run in errors (e.g. "design")."""

    def __init__(self, targets, names=None, *, device: str = "cpu", job: str = "control", centre: bool = True,
                 labels=None):
        meshes = centred_targets(targets, job, centre)
        names = list(names) if names is not None else [f"target{j}" for j in range(len(meshes))]
        if len(names) != len(meshes):
            raise DesignError(f"{len(names)} target names for {len(meshes)} targets")
        self.all_targets = tuple(meshes)
        self.all_names = tuple(names)
        self.labels = tuple(labels) if labels is not None else tuple(checks.target_labels(meshes, names))
        self.all_volumes = np.array([t.volume() for t in meshes])
        self.device = str(device)
        self.index = tuple(range(len(meshes)))
        self.token = (os.getpid(), next(_TOKENS))
        # shared by every take: the (rest key, target index) pairs checked against the device, and whether
        # the targets' star-shape check has run
        self.record = dict(checked=set(), star_checked=False)

    # -------------------------------------------------------------------- the worlds' targets
    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, w):
        if isinstance(w, slice):
            return [self.all_targets[i] for i in self.index[w]]
        return self.all_targets[self.index[w]]

    @property
    def targets(self) -> list[TriMesh]:
        """The centred target of every world."""
        return [self.all_targets[i] for i in self.index]

    @property
    def names(self) -> list[str]:
        return [self.all_names[i] for i in self.index]

    @property
    def volumes(self) -> np.ndarray:
        """(W,) each world's target volume, m^3."""
        return self.all_volumes[list(self.index)]

    def take(self, indices) -> "Problem":
        """The problem of this one's worlds ``indices`` (repeats allowed), sharing its sampler and checks."""
        out = object.__new__(Problem)
        out.__dict__.update(self.__dict__)
        out.index = tuple(self.index[int(i)] for i in indices)
        if not out.index:
            raise DesignError("a problem needs at least one target")
        return out

    # -------------------------------------------------------------------- sampler and checks
    def full_sampler(self) -> RadialSampler:
        """The sampler of every target of the problem, built once per process (``SAMPLERS``); the first
        build checks that every target is star-shaped."""
        key = (self.token, self.device)
        if key not in SAMPLERS:
            SAMPLERS[key] = RadialSampler(list(self.all_targets), device=self.device,
                                          check=not self.record["star_checked"], names=list(self.labels))
            while len(SAMPLERS) > _KEEP:
                SAMPLERS.popitem(last=False)
        self.record["star_checked"] = True
        SAMPLERS.move_to_end(key)
        return SAMPLERS[key]

    @property
    def sampler(self) -> RadialSampler:
        """The sampler of the worlds' targets: world w samples its target as target w."""
        full = self.full_sampler()
        return full if self.index == tuple(range(full.n_targets)) else full.subset(self.index)

    def check_rest(self, rest: TriMesh, max_stretch: float) -> None:
        """``controller.checks.check_targets_against_rest`` for the worlds' targets against ``rest``, each
        target checked once per rest shape and ``max_stretch`` in the run."""
        key = _rest_key(rest, max_stretch)
        checked = self.record["checked"]
        todo = sorted({i for i in self.index if (key, i) not in checked})
        if not todo:
            return
        sampler = self.full_sampler()
        checks.check_targets_against_rest(rest, [self.all_targets[i] for i in todo], sampler.subset(todo),
                                          [self.labels[i] for i in todo], max_stretch=max_stretch)
        checked.update((key, i) for i in todo)


def as_problem(targets, names=None, *, device: str = "cpu", centre: bool = True, job: str = "control") -> Problem:
    """``targets`` as a ``Problem`` on ``device``: itself where it is one there, else one built
    (centred unless ``centre`` is False)."""
    if isinstance(targets, Problem):
        if targets.device == str(device):
            return targets
        return Problem(targets.targets, targets.names, device=device, job=job, centre=False)
    return Problem(targets, names, device=device, job=job, centre=centre)


def take(targets, indices):
    """Targets ``indices`` (repeats allowed) of a ``Problem`` (``Problem.take``: sharing its sampler and
    checks) or of a list of meshes (a list)."""
    if isinstance(targets, Problem):
        return targets.take(indices)
    return [targets[int(i)] for i in indices]
