"""Upper bounds of the sizes a run may request: IPAMs, candidates, rounds, steps, worlds, mesh resolution.

Each is well past what the paper and the shipped scenes use, and below what exhausts a workstation's
memory or disk. The command-line flags that size a run and a sweep's settings (``--set``/``--param``)
are held to them before any work.
"""

from __future__ import annotations

__all__ = ["MAX_ACTUATORS", "MAX_CANDIDATES", "MAX_REFINE_ROUNDS", "MAX_CONTROL_STEPS", "MAX_SIM_STEPS",
           "MAX_WORLDS", "MAX_SUBDIVISIONS", "MAX_CONTROL_PERIOD", "MAX_INVERSE_ITERATIONS", "MAX_SUBSTEPS",
           "MAX_IPAMS"]

#: the most IPAMs a design holds (the paper's displays have 4-20; each adds controller worlds and steps)
MAX_IPAMS = 1000
MAX_ACTUATORS = 500  # IPAMs placed (the shipped problems place 4..20)
MAX_CANDIDATES = 256  # holds or candidate sets per round, each a world of one batch
MAX_REFINE_ROUNDS = 50
MAX_CONTROL_STEPS = 100_000  # control steps of one run (default 300); also the settle steps
MAX_SIM_STEPS = 200_000  # output steps of `simulate` (default 800)
MAX_WORLDS = 4096
MAX_SUBDIVISIONS = 6  # icosphere subdivisions of a membrane (6: 40,962 vertices)
MAX_CONTROL_PERIOD = 1000  # output steps per control step (default 10)
MAX_INVERSE_ITERATIONS = 1000  # inverse-control iterations per control step (default 6)
MAX_SUBSTEPS = 1_000_000  # internal steps per output step (the automatic cap is 10,000)
