"""The force families of the membrane model, one module each: its launch wrapper and host-side law.

Each family module (springs, bending, pressure, ipam, jamming, damping) holds the thin ``eval_*``
wrapper that launches its kernel (skipping work the model does not need) and its law in float64
NumPy, batched over worlds: energy, the quantities the simulator reports and its contribution to
the stable-step bound. Wrappers take a ``launch(kernel, dim, inputs)`` callable so the same code
path serves direct launches, recorded launches and graph capture.
"""

from __future__ import annotations

from typing import Callable

import warp as wp

__all__ = ["FORCE_TERMS", "Launch"]

#: the force terms a read-out can ask for, one per family ('spring' includes its dampers)
FORCE_TERMS = ("spring", "bending", "pressure", "ipam", "viscous")

#: launch(kernel, dim, inputs): a direct launch, a recorded one or one inside a graph capture
Launch = Callable[[wp.Kernel, tuple, list], None]
