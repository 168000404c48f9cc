"""Host-side description of a shape display: rest membrane, IPAMs and jamming cells."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from .errors import DesignError, check_number
from .limits import MAX_IPAMS
from .material import Material
from .mesh import TriMesh
from .physics.ipam_law import natural_length_np, pressure_for_length_np

__all__ = ["Design", "Ipam", "Cell", "MAX_IPAMS"]

# IPAM defaults: a soft latex tube (bore ~4.4 mm) in a fabric sheath. A / k = 3e-7 m/Pa gives
# ~30 mm of extension at 100 kPa, the large strains the paper's actuators reach.
DEFAULT_IPAM_STIFFNESS = 50.0  # N/m
DEFAULT_IPAM_AREA = 1.5e-5  # m^2
DEFAULT_IPAM_DAMPING = 5.0e-3  # N s/m per sub-spring
DEFAULT_IPAM_PRESSURE_LIMITS = (-50.0e3, 300.0e3)  # Pa gauge


@dataclass(frozen=True)
class Ipam:
    """An inverse pneumatic artificial muscle joining the centroids of faces ``face_a`` and ``face_b``.

    Axial force F = k (L - L_n), L_n = L0 + (A/k) P (positive = tension). Modelled as three springs
    of stiffness k/3 joining ``pairs[s] = (vertex of a, vertex of b)``; sub-spring s has natural
    length L_n + ``offsets[s]`` (its rest length minus the rest centroid distance).
    """

    face_a: int
    face_b: int
    stiffness: float  # k, N/m
    area: float  # A, m^2
    free_length: float  # L0, m
    pressure_limits: tuple[float, float]  # (P_min, P_max), Pa gauge
    damping: float  # N s/m per sub-spring
    pairs: np.ndarray = field(repr=False)  # (3, 2) int32
    offsets: np.ndarray = field(repr=False)  # (3,) float64, m
    rest_length: float = 0.0  # rest centroid distance, m

    @property
    def area_over_stiffness(self) -> float:
        """A / k in m/Pa: natural-length change per pascal."""
        return self.area / self.stiffness

    @property
    def free_length_is_rest(self) -> bool:
        """Whether L0 is the rest centroid distance (``add_ipam(free_length=None)``): it then follows
        the rest shape."""
        return abs(self.free_length - self.rest_length) <= 1e-12 * self.rest_length

    def natural_length(self, pressure: float) -> float:
        """Natural length L_n = L0 + (A/k) P in m at gauge pressure ``pressure`` (Pa)."""
        return natural_length_np(self.free_length, self.area_over_stiffness, pressure)

    def pressure_for_length(self, length: float) -> float:
        """Gauge pressure at which the natural length equals ``length``."""
        return pressure_for_length_np(self.free_length, self.area_over_stiffness, length)


@dataclass(frozen=True)
class Cell:
    """A particle-jamming cell: a set of membrane faces jammed together."""

    faces: np.ndarray  # (n,) int32, sorted


def _unit_hint(value: float, scale: float, unit: str) -> str:
    """"15 mm^2 is 1.5e-05": the value read in ``unit`` (``scale`` SI units each), as it should be given."""
    return f"if {value:g} {unit} was meant, give {value * scale:g}"


class Design:
    """Rest membrane + material + IPAMs + jamming cells (host description, SI units)."""

    def __init__(self, rest: TriMesh, material: Material | None = None):
        if not isinstance(rest, TriMesh):
            raise DesignError(f"Design.rest must be a TriMesh (ws.icosphere, ws.TriMesh.load), got {type(rest).__name__}")
        if material is None:
            material = Material()
        if not isinstance(material, Material):
            raise DesignError(f"Design.material must be a ws.Material, got {type(material).__name__}")
        self.rest = rest
        self.material = material
        self._check_thickness()
        self.actuators: dict[str, list] = {"ipam": []}  # the elements of each actuator family, by family name
        self.cells: list[Cell] = []
        self._face_cell = np.full(rest.n_faces, -1, dtype=np.int64)
        self.stretch_scale: np.ndarray | None = None  # (F,) multiplier of E t per face; None: uniform

    @property
    def size(self) -> float:
        """The device's radius (m): half the rest mesh's largest extent."""
        return 0.5 * float(np.max(np.ptp(self.rest.vertices, axis=0)))

    def _check_thickness(self) -> None:
        """A membrane thicker than the whole device is a length in another unit: refused, naming it."""
        t, size = float(self.material.thickness), self.size
        if size > 0 and t > 2 * size:
            raise DesignError(f"material thickness {t:g} m is more than the whole device ({2e3 * size:.1f} mm across); "
                              f"lengths are in metres: {_unit_hint(t, 1e-3, 'mm')}")

    def _check_area(self, area: float) -> None:
        """An IPAM area above the device's own cross-section is an area in another unit: refused, naming it."""
        size = self.size
        if size > 0 and area > np.pi * size ** 2:
            raise DesignError(f"IPAM area {area:g} m^2 is more than the device's cross-section "
                              f"({np.pi * size ** 2:.3g} m^2 at {1e3 * size:.1f} mm radius); areas are in m^2: "
                              f"{_unit_hint(area, 1e-6, 'mm^2')}")

    # ------------------------------------------------------------------ material
    def set_stretch_scale(self, scale) -> None:
        """Give each face its own multiplier of the material's E t (``scale`` (F,), > 0; None: uniform):
        a membrane stiffer or softer in places (a calibration's regions). An edge's stretch stiffness is
        E t (s_a A_a + s_b A_b) / L^2 over its two faces a, b."""
        if scale is None:
            self.stretch_scale = None
            return
        s = np.asarray(scale, dtype=np.float64).reshape(-1)
        if s.size != self.rest.n_faces:
            raise DesignError(f"stretch_scale has {s.size} values but the rest mesh has {self.rest.n_faces} faces: "
                              f"give one multiplier of E t per face")
        if not np.all(np.isfinite(s) & (s > 0)):
            raise DesignError("stretch_scale values must be positive numbers (multipliers of E t)")
        self.stretch_scale = None if np.all(s == 1.0) else s.copy()

    # ------------------------------------------------------------------ copies
    def replace(self, *, rest: TriMesh | None = None, material: Material | None = None, ipams=None,
                stretch_scale=False) -> "Design":
        """A copy of this design with its rest mesh, material, IPAMs or per-face stretch scale replaced where
        given: the one rule every rebuild follows. Every other force family's elements, every cell (cells
        that share faces stay shared) and the stretch scale (``stretch_scale`` False: kept; None: uniform)
        are kept. ``ipams``: a list of ``Ipam`` values (e.g. ``dataclasses.replace(ip, area=...)``), None to
        keep them; an IPAM whose free length is its rest centroid distance (``free_length_is_rest``) gets
        the new rest shape's, others keep theirs."""
        out = Design(self.rest if rest is None else rest, self.material if material is None else material)
        for ip in self.ipams if ipams is None else ipams:
            out.add_ipam(ip.face_a, ip.face_b, stiffness=ip.stiffness, area=ip.area,
                         free_length=None if ip.free_length_is_rest else ip.free_length,
                         pressure_limits=ip.pressure_limits, damping=ip.damping)
        for family, elements in self.actuators.items():
            if family != "ipam":
                for e in elements:
                    out.add_element(family, e)
        shared = bool(self.cells) and np.bincount(np.concatenate([c.faces for c in self.cells])).max() > 1
        for c in self.cells:
            out.add_cell(c.faces, shared=shared)
        out.set_stretch_scale(self.stretch_scale if stretch_scale is False else stretch_scale)
        return out

    # ------------------------------------------------------------------ actuators
    @property
    def ipams(self) -> list[Ipam]:
        """The IPAMs (the elements of the "ipam" actuator family)."""
        return self.actuators["ipam"]

    def elements(self, family: str) -> list:
        """The elements of actuator family ``family`` (a list, empty when the design has none)."""
        return self.actuators.setdefault(family, [])

    def add_element(self, family: str, element) -> int:
        """Append ``element`` to actuator family ``family``'s elements (an ``ActuatorFamily`` builds and
        checks it); returns its index among them."""
        if not isinstance(family, str) or not family.isidentifier():
            raise DesignError(f"an actuator family is named by an identifier, got {family!r}")
        elements = self.elements(family)
        elements.append(element)
        return len(elements) - 1

    def check_vertex(self, vertex, what: str) -> int:
        """``vertex`` as a vertex index of the rest mesh; anything else raises ``DesignError`` naming ``what``."""
        return self._check_index(vertex, self.rest.n_vertices, "vertex", "vertices", what)

    def check_face(self, face, what: str) -> int:
        """``face`` as a face index of the rest mesh; anything else raises ``DesignError`` naming ``what``."""
        return self._check_index(face, self.rest.n_faces, "face", "faces", what)

    @staticmethod
    def _check_index(value, count: int, kind: str, plural: str, what: str) -> int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise DesignError(f"{what} must be a {kind} index (int), got {value!r}")
        value = int(value)
        if not 0 <= value < count:
            raise DesignError(f"{what} = {value} is out of range: the rest mesh has {count} {plural}")
        return value

    def add_ipam(self, face_a, face_b, stiffness: float = DEFAULT_IPAM_STIFFNESS, area: float = DEFAULT_IPAM_AREA,
                 free_length: float | None = None, pressure_limits=DEFAULT_IPAM_PRESSURE_LIMITS,
                 damping: float = DEFAULT_IPAM_DAMPING) -> int:
        """Add an IPAM between two faces; returns its index.

        ``free_length`` None means the rest centroid distance (no force at zero gauge pressure in
        the rest shape). ``pressure_limits`` = (P_min, P_max) gauge Pa with P_min >= -p_atm.
        """
        if len(self.ipams) >= MAX_IPAMS:
            raise DesignError(f"a design holds at most {MAX_IPAMS} IPAMs (the paper's displays have 4-20); use fewer")
        a = self.check_face(face_a, "IPAM face_a")
        b = self.check_face(face_b, "IPAM face_b")
        if a == b:
            raise DesignError(f"IPAM ends coincide (both on face {a}); join two different faces")
        fa, fb = self.rest.faces[a], self.rest.faces[b]
        shared = sorted(set(fa.tolist()) & set(fb.tolist()))
        if shared:
            raise DesignError(
                f"IPAM faces {a} and {b} share vertex {shared[0]}: an actuator between touching faces "
                f"has a zero-length sub-spring; join faces that share no vertex")
        stiffness, area, damping = (check_number(v, f"IPAM {name}") for name, v in
                                    (("stiffness", stiffness), ("area", area), ("damping", damping)))
        if free_length is not None:
            free_length = check_number(free_length, "IPAM free_length")
        if stiffness <= 0 or area <= 0:
            raise DesignError(f"IPAM stiffness and area must be > 0 (N/m, m^2), got {stiffness}, {area}")
        self._check_area(area)
        if damping < 0:
            raise DesignError(f"IPAM damping must be >= 0 N s/m, got {damping}")
        try:
            lo, hi = (check_number(p, "pressure_limits") for p in pressure_limits)
        except (TypeError, ValueError):
            raise DesignError(f"pressure_limits must be a pair of finite numbers (P_min, P_max) in Pa gauge, "
                              f"got {pressure_limits!r}") from None
        p_atm = self.material.atmospheric_pressure
        if lo > hi:
            raise DesignError(f"pressure_limits must satisfy P_min <= P_max, got ({lo}, {hi})")
        if lo < -p_atm:
            raise DesignError(f"pressure_limits P_min = {lo} Pa is below full vacuum (-{p_atm} Pa gauge)")

        x = self.rest.vertices
        ca, cb = x[fa].mean(axis=0), x[fb].mean(axis=0)
        rest_length = float(np.linalg.norm(cb - ca))
        best, best_perm = math.inf, None
        for perm in itertools.permutations(fb.tolist()):
            total = float(np.linalg.norm(x[list(perm)] - x[fa], axis=1).sum())
            if total < best:
                best, best_perm = total, perm
        pairs = np.stack([fa, np.array(best_perm)], axis=1).astype(np.int32)
        sub_rest = np.linalg.norm(x[pairs[:, 1]] - x[pairs[:, 0]], axis=1)
        if free_length is None:
            free_length = rest_length
        if not (math.isfinite(free_length) and free_length > 0):
            raise DesignError(f"IPAM free_length must be a positive length in m, got {free_length!r}")
        ipam = Ipam(face_a=a, face_b=b, stiffness=float(stiffness), area=float(area),
                    free_length=float(free_length), pressure_limits=(lo, hi), damping=float(damping),
                    pairs=pairs, offsets=sub_rest - rest_length, rest_length=rest_length)
        return self.add_element("ipam", ipam)

    def add_cell(self, faces, shared: bool = False) -> int:
        """Add a jamming cell over these face indices; returns its index. Cells may not overlap, except
        with ``shared`` True: a model holding alternative actuator sets (designer candidates, each
        world masking out all but its own) may hold cells that share faces; ``face_cell`` keeps the
        first cell of a shared face."""
        try:
            arr = np.unique(np.asarray(faces).reshape(-1))
        except (ValueError, TypeError) as exc:  # ragged nesting, unorderable objects
            raise DesignError(f"cell faces must be a flat list of integer face indices, got {faces!r} ({exc})") from None
        if arr.size == 0:
            raise DesignError("a jamming cell needs at least one face")
        if not np.issubdtype(arr.dtype, np.integer):
            raise DesignError(f"cell faces must be integer face indices, got dtype {arr.dtype}")
        bad = arr[(arr < 0) | (arr >= self.rest.n_faces)]
        if bad.size:
            raise DesignError(f"cell face {int(bad[0])} is out of range: the rest mesh has {self.rest.n_faces} faces")
        taken = self._face_cell[arr]
        if np.any(taken >= 0) and not shared:
            i = int(np.flatnonzero(taken >= 0)[0])
            raise DesignError(f"cell face {int(arr[i])} already belongs to cell {int(taken[i])}; cells may not overlap")
        self.cells.append(Cell(faces=arr.astype(np.int32)))
        self._face_cell[arr[taken < 0]] = len(self.cells) - 1
        return len(self.cells) - 1

    # ------------------------------------------------------------------ queries
    @property
    def n_ipams(self) -> int:
        """Number of IPAMs."""
        return len(self.ipams)

    @property
    def n_cells(self) -> int:
        """Number of jamming cells."""
        return len(self.cells)

    def face_cell(self) -> np.ndarray:
        """(F,) cell index of every face, -1 where none."""
        return self._face_cell.copy()

    def cell_edges(self, cell: int) -> np.ndarray:
        """Sorted edge indices of every face of a cell."""
        topo = self.rest.topology
        return np.unique(topo.face_edges[self.cells[cell].faces].reshape(-1)).astype(np.int32)

    def __repr__(self) -> str:
        others = "".join(f", {k}={len(v)}" for k, v in self.actuators.items() if k != "ipam" and v)
        return f"Design(rest={self.rest!r}, ipams={self.n_ipams}{others}, cells={self.n_cells})"
