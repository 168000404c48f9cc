"""Sweeps: many designs at once, on Ray or one after another (the paper's Fig. 11 and Fig. 12 studies).

``sweep(kind="subsets", targets=[...], actuators=5)`` designs for every non-empty subset of the
targets; ``sweep(kind="grid", params={"actuators": [5, 10, 20]})`` for every point of a grid of
designer, controller, simulation or material settings. Each run is the job ``warp-shape design``
does, with its outputs in ``DIR/runs/<run_id>/``; ``DIR/results.csv`` and ``results.json`` get one
row per run as runs finish; ``summary.md`` and ``summary.png`` sum them up. Runs execute as Ray tasks
(a local instance, or a cluster at ``address``) or serially in this process. docs/sweeps.md.

Modules: ``params`` (which setting a name means, values checked), ``plan`` (the problem and one task
per run), ``run`` (one run: design and outputs), ``results`` (the streamed table), ``backends``
(serial and Ray), ``summary`` (Markdown table and figure), ``api`` (``sweep``).
"""

from .api import KINDS, SweepResult, sweep
from .backends import BACKENDS
from .params import SweepError, known_params, parse_param
from .plan import RunTask
from .run import execute

__all__ = ["sweep", "SweepResult", "SweepError", "KINDS", "BACKENDS", "RunTask", "execute", "known_params",
           "parse_param"]
