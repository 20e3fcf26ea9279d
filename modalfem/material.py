"""Isotropic linear elastic material."""

from __future__ import annotations

import math
from dataclasses import dataclass

from modalfem.errors import MaterialError

__all__ = ["Material", "STEEL", "ALUMINIUM", "BRASS", "MATERIALS"]


@dataclass(frozen=True)
class Material:
    """Isotropic linear elastic material, validated on construction.

    Args:
        E: Young's modulus [Pa], > 0.
        nu: Poisson's ratio [-], strictly inside (-1, 0.5).
        rho: density [kg/m^3], > 0.
        name: optional label used in reports.

    Raises:
        MaterialError: a value is not finite or outside its physical range.
    """

    E: float
    nu: float
    rho: float
    name: str = ""

    def __post_init__(self) -> None:
        for field, value in (("E", self.E), ("nu", self.nu), ("rho", self.rho)):
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise MaterialError(f"material {field} must be a number, got {value!r}") from None
            if not math.isfinite(v):
                raise MaterialError(f"material {field} must be finite, got {value!r}")
            object.__setattr__(self, field, v)
        if self.E <= 0:
            raise MaterialError(f"Young's modulus E must be > 0 Pa, got {self.E:g}")
        if not (-1.0 < self.nu < 0.5):
            raise MaterialError(f"Poisson's ratio nu must lie in (-1, 0.5), got {self.nu:g}")
        if self.rho <= 0:
            raise MaterialError(f"density rho must be > 0 kg/m^3, got {self.rho:g}")

    @property
    def lame_lambda(self) -> float:
        """First Lame parameter lambda [Pa]."""
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def shear_modulus(self) -> float:
        """Shear modulus mu = G [Pa]."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def wave_speed(self) -> float:
        """Bar (rod) wave speed sqrt(E / rho) [m/s]."""
        return math.sqrt(self.E / self.rho)


STEEL = Material(E=200e9, nu=0.3, rho=7850.0, name="steel")
ALUMINIUM = Material(E=69e9, nu=0.33, rho=2700.0, name="aluminium")
BRASS = Material(E=100e9, nu=0.34, rho=8500.0, name="brass")
MATERIALS = {m.name: m for m in (STEEL, ALUMINIUM, BRASS)}
