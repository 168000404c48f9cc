"""Membrane material: the constants of the mass-spring model (SI units)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from .errors import DesignError, check_number

__all__ = ["Material", "GAS_CONSTANT"]

GAS_CONSTANT = 8.314462618  # J / (mol K)
#: the highest ``atmospheric_pressure`` accepted, Pa (100 atm; sea level is 101325 Pa)
MAX_ATMOSPHERIC_PRESSURE = 1.0e7


@dataclass(frozen=True)
class Material:
    """Constants of the membrane model, SI units throughout.

    The defaults describe the paper's device: two brush-molded Ecoflex 00-30 membranes with a
    coffee-ground jamming layer between them, about 8 cm across.

    youngs_modulus: E in Pa. Ecoflex 00-30 has a 100 % modulus of about 69 kPa.
    thickness: t in m, the load-bearing silicone thickness (two ~1 mm membranes). Edge springs use
        k_e = E t A(T_e) / c^2 (the paper folds t into E).
    areal_density: rho_A in kg/m^2: 2 mm of silicone (~2.1 kg/m^2) plus ~4 mm of loose dry coffee
        grounds (~1.4 kg/m^2).
    bending_stiffness: k_t in N m/rad of every dihedral (hinge) spring, the same on all edges as in
        the paper. ~1e-4 is the plate bending stiffness E t^3 / 12 (1 - nu^2) of the 2 mm membrane
        times the ~sqrt(3) hinge factor of an equilateral mesh; the unjammed layer adds little.
    spring_damping: c_s in N s/m, linear damper along each edge spring.
    viscous_damping: c_v in N s/m, force -c_v v on every vertex (per vertex, as in the paper).
    jam_stretch_factor / jam_bend_factor: stiffness multipliers of the edge and hinge springs of a
        jammed cell (paper: 10 and 30).
    temperature: T in K of the chamber air (isothermal). atmospheric_pressure: p_atm in Pa (absolute).
    """

    youngs_modulus: float = 69.0e3
    thickness: float = 2.0e-3
    areal_density: float = 3.5
    bending_stiffness: float = 1.0e-4
    spring_damping: float = 5.0e-3
    viscous_damping: float = 2.0e-2
    jam_stretch_factor: float = 10.0
    jam_bend_factor: float = 30.0
    temperature: float = 293.15
    atmospheric_pressure: float = 101325.0

    def __post_init__(self):
        positive = ("youngs_modulus", "thickness", "areal_density", "temperature")
        non_negative = ("bending_stiffness", "spring_damping", "viscous_damping", "atmospheric_pressure")
        at_least_one = ("jam_stretch_factor", "jam_bend_factor")
        for f in fields(self):
            object.__setattr__(self, f.name, check_number(getattr(self, f.name), f"Material.{f.name}"))
        for name in positive:
            if getattr(self, name) <= 0:
                raise DesignError(f"Material.{name} must be > 0 (SI units), got {getattr(self, name)!r}")
        for name in non_negative:
            if getattr(self, name) < 0:
                raise DesignError(f"Material.{name} must be >= 0 (SI units), got {getattr(self, name)!r}")
        if self.atmospheric_pressure > MAX_ATMOSPHERIC_PRESSURE:
            raise DesignError(f"Material.atmospheric_pressure = {self.atmospheric_pressure:g} Pa is no atmosphere (sea "
                              f"level is 101325 Pa; at most {MAX_ATMOSPHERIC_PRESSURE:g} Pa, 100 atm, is accepted); "
                              f"give it in Pa (absolute)")
        for name in at_least_one:
            if getattr(self, name) < 1:
                raise DesignError(f"Material.{name} must be >= 1 (jamming stiffens), got {getattr(self, name)!r}")

    @property
    def stretch_modulus(self) -> float:
        """E t in N/m."""
        return self.youngs_modulus * self.thickness

    def to_dict(self) -> dict:
        """Every field by name, SI units."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Material":
        """A Material from ``to_dict`` output; unknown fields raise ``DesignError``."""
        if not isinstance(d, dict):
            raise DesignError(f"Material.from_dict needs a dict {{field: value}}, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(str(k) for k in set(d) - known)
        if unknown:
            raise DesignError(f"unknown Material field(s) {unknown}; known fields are {sorted(known)}")
        return cls(**dict(d))
