"""warp_shape: simulator and automatic design tool for soft 3-D haptic shape displays."""

from .errors import DesignError, MeshError, SimulationError, StabilityError, WarpShapeError
from .mesh import TriMesh, icosphere

__version__ = "0.1.0"
