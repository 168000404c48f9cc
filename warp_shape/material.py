"""Membrane material: the constants of the mass-spring model (SI units)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from .errors import DesignError, check_number

__all__ = ["Material", "GAS_CONSTANT", "MEMBRANE_LAWS", "PLATE_POISSON"]

GAS_CONSTANT = 8.314462618  # J / (mol K)
#: the highest ``atmospheric_pressure`` accepted, Pa (100 atm; sea level is 101325 Pa)
MAX_ATMOSPHERIC_PRESSURE = 1.0e7
#: the membrane laws: the paper's edge-spring lattice, and two thin incompressible hyperelastic sheets
MEMBRANE_LAWS = ("springs", "neo_hookean", "yeoh")
#: what a hyperelastic sheet does in compression: "solid" resists it (I1 > 3 for any stretch but the
#: identity), "tension_field" wrinkles (docs/membrane.md): no stress across a wrinkled direction, none
#: at all where both principal stretches are below 1
COMPRESSION_MODES = ("solid", "tension_field")
#: Poisson's ratio of the plate bending stiffness E t^3 / 12 (1 - nu^2) of the hyperelastic laws
#: (incompressible rubber)
PLATE_POISSON = 0.5
#: fields that are not plain numbers (checked on their own)
_SPECIAL = ("membrane", "shear_modulus", "compression")


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
    membrane: the membrane law (SPEC section 15; docs/membrane.md). "springs": the paper's edge-spring
        lattice (k_e above, bending_stiffness on every hinge). "neo_hookean" / "yeoh": a thin
        incompressible hyperelastic sheet on the triangles (plane stress, the thickness following the
        stretch), strain energy per unit rest area t W(I1), W = C1 (I1 - 3) + C2 (I1 - 3)^2
        + C3 (I1 - 3)^3, C1 = mu / 2; the edge springs then carry no elastic force (their dampers
        stay) and the hinges take the plate stiffness E t^3 / 12 (1 - nu^2), nu = 0.5, through the
        discrete-shell weighting 3 |e|^2 / A_e (bending_stiffness is then unused).
    shear_modulus: mu in Pa of the hyperelastic laws; None: E / 3 (the small-strain shear modulus of
        an incompressible solid of Young's modulus E).
    yeoh_c2 / yeoh_c3: C2 and C3 in Pa of the Yeoh law (must be 0 for "neo_hookean" and "springs").
    compression: the hyperelastic sheet in compression (``COMPRESSION_MODES``): "solid" (default) or
        "tension_field" (the sheet wrinkles instead of carrying a compressive stress; springs: "solid").
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
    membrane: str = "springs"
    shear_modulus: float | None = None
    yeoh_c2: float = 0.0
    yeoh_c3: float = 0.0
    compression: str = "solid"

    def __post_init__(self):
        positive = ("youngs_modulus", "thickness", "areal_density", "temperature")
        non_negative = ("bending_stiffness", "spring_damping", "viscous_damping", "atmospheric_pressure")
        at_least_one = ("jam_stretch_factor", "jam_bend_factor")
        self._check_membrane()
        for f in fields(self):
            if f.name in _SPECIAL:
                continue
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

    def _check_membrane(self) -> None:
        """The membrane law's fields: a known law, mu > 0 or None, and Yeoh terms only for "yeoh"."""
        if self.membrane not in MEMBRANE_LAWS:
            raise DesignError(f"Material.membrane must be one of {list(MEMBRANE_LAWS)}, got {self.membrane!r}")
        if self.shear_modulus is not None:
            mu = check_number(self.shear_modulus, "Material.shear_modulus")
            if mu <= 0:
                raise DesignError(f"Material.shear_modulus must be > 0 Pa (or None for E / 3), got {mu!r}")
            object.__setattr__(self, "shear_modulus", mu)
        if self.compression not in COMPRESSION_MODES:
            raise DesignError(f"Material.compression must be one of {list(COMPRESSION_MODES)}, got {self.compression!r}")
        if self.compression != "solid" and self.membrane == "springs":
            raise DesignError("Material.compression = 'tension_field' is a hyperelastic sheet's; set membrane="
                              "'neo_hookean' or 'yeoh' (the springs carry compression as the paper's lattice)")
        for name in ("yeoh_c2", "yeoh_c3"):
            value = check_number(getattr(self, name), f"Material.{name}")
            if value != 0.0 and self.membrane != "yeoh":
                raise DesignError(f"Material.{name} = {value:g} Pa is a Yeoh term; set membrane='yeoh' to use it "
                                  f"(membrane is {self.membrane!r})")
            if value < 0:
                raise DesignError(f"Material.{name} must be >= 0 Pa (a stiffening Yeoh term), got {value!r}")
            object.__setattr__(self, name, value)

    @property
    def hyperelastic(self) -> bool:
        """True for the hyperelastic membrane laws (not the paper's springs)."""
        return self.membrane != "springs"

    @property
    def mu(self) -> float:
        """The shear modulus mu in Pa in effect: ``shear_modulus``, or E / 3 when None."""
        return self.youngs_modulus / 3.0 if self.shear_modulus is None else self.shear_modulus

    def membrane_summary(self) -> dict:
        """The membrane law and the constants it reads, keys with their units (a report's ``membrane``)."""
        out = {"law": self.membrane, "thickness_m": self.thickness}
        if self.hyperelastic:
            out.update(shear_modulus_pa=self.mu, compression=self.compression,
                       plate_stiffness_n_m=self.plate_stiffness)
            if self.membrane == "yeoh":
                out.update(yeoh_c2_pa=self.yeoh_c2, yeoh_c3_pa=self.yeoh_c3)
        else:
            out.update(youngs_modulus_pa=self.youngs_modulus, bending_stiffness_n_m_per_rad=self.bending_stiffness)
        return out

    def membrane_line(self) -> str:
        """One line naming the membrane law and its constants (mm, kPa), for reports."""
        t = f"t {self.thickness * 1e3:.2f} mm"
        if not self.hyperelastic:
            return (f"Membrane: the paper's edge-spring lattice (E {self.youngs_modulus / 1e3:.1f} kPa, {t}, "
                    f"bending {self.bending_stiffness:.3g} N m/rad on every hinge).")
        law = "neo-Hookean" if self.membrane == "neo_hookean" else "Yeoh"
        yeoh = (f", C2 {self.yeoh_c2 / 1e3:.3g} kPa, C3 {self.yeoh_c3 / 1e3:.3g} kPa"
                if self.membrane == "yeoh" else "")
        return (f"Membrane: a thin incompressible {law} sheet (mu {self.mu / 1e3:.2f} kPa{yeoh}, {t}, plate "
                f"bending {self.plate_stiffness:.3g} N m; in compression: {self.compression.replace('_', ' ')}).")

    @property
    def yeoh_constants(self) -> tuple:
        """(C1, C2, C3) in Pa of the hyperelastic law (C1 = mu / 2)."""
        return 0.5 * self.mu, self.yeoh_c2, self.yeoh_c3

    @property
    def plate_stiffness(self) -> float:
        """D = E t^3 / 12 (1 - nu^2) in N m with nu = ``PLATE_POISSON`` and E = 3 mu (the hyperelastic
        laws' bending)."""
        return 3.0 * self.mu * self.thickness ** 3 / (12.0 * (1.0 - PLATE_POISSON ** 2))

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
