"""warp_shape: simulator and automatic design tool for soft 3-D haptic shape displays.

Quick start::

    import warp_shape as ws
    d = ws.Design(rest=ws.icosphere(3, 0.04), material=ws.Material())
    sim = ws.Simulator(d, device="cpu")
    sim.air_moles *= 1.05
    sim.step(100)
"""

from .design import Cell, Design, Ipam
from .errors import DesignError, MeshError, SimulationError, StabilityError, WarpShapeError
from .material import GAS_CONSTANT, Material
from .mesh import TriMesh, icosphere
from .simulator import Simulator
from .solver import FORCE_TERMS

__version__ = "0.1.0"
