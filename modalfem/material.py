"""Isotropic linear elastic material."""

from __future__ import annotations

import math
from dataclasses import dataclass

from modalfem.errors import MaterialError

__all__ = ["Material", "STEEL", "ALUMINIUM", "BRASS", "MATERIALS", "E_RANGE", "RHO_RANGE", "E_OVER_RHO_RANGE"]

#: Young's modulus E [Pa] that modalfem computes soundly (see ``Material``)
E_RANGE = (1e-100, 1e100)
#: density rho [kg/m^3] that modalfem computes soundly (see ``Material``)
RHO_RANGE = (1e-100, 1e100)
#: E / rho [m^2/s^2] (squared bar wave speed) that modalfem computes soundly (see ``Material``)
E_OVER_RHO_RANGE = (1e-100, 1e100)

_WHY = {
    "E": "stiffness entries ~ E*h/((1+nu)(1-2nu)) (up to 1e16*E*h)",
    "rho": "mass entries ~ rho*h^3",
    "E/rho": "eigenvalues omega^2 ~ E/(rho*h^2) (up to 1e16*E/(rho*h^2))",
}


@dataclass(frozen=True)
class Material:
    """Isotropic linear elastic material, validated on construction.

    Args:
        E: Young's modulus [Pa], in ``E_RANGE`` = [1e-100, 1e100].
        nu: Poisson's ratio [-], strictly inside (-1, 0.5).
        rho: density [kg/m^3], in ``RHO_RANGE`` = [1e-100, 1e100].
        name: optional label used in reports.

    Besides, ``E / rho`` [m^2/s^2] (the squared bar wave speed) must lie in ``E_OVER_RHO_RANGE`` =
    [1e-100, 1e100]. Every real material (E from ~1e3 Pa for gels to ~1.2e12 Pa for diamond,
    rho from ~1 to ~2.3e4 kg/m^3) and every non-dimensional use (E = rho = 1) is far inside.

    Why these ranges: the eigen solvers form squares and products of what the assembly builds
    (norms, Rayleigh quotients, residuals ``||K x - omega^2 M x||``), so each such quantity must
    stay within the square root of the double-precision range, 1e-154 .. 1e154, or its square
    over- or underflows (E = 1e308 then ends in a LinAlgError, E = 1e-300 in a cascade of
    RuntimeWarnings; measured: E or rho alone fail beyond ~1e+-150, E/rho beyond ~1e+-150). The
    quantities, for elements of size h (1e-7 m for a finely meshed 0.1 mm part to 50 m) are:

    * stiffness entries ~ E h (1 - nu) / ((1 + nu)(1 - 2 nu)); the nu factor is at most ~1e16
      for any double-precision nu in (-1, 0.5) (1 + nu and 1 - 2 nu are at least ~1.1e-16), so
      they lie in [1e-107, 5e117] for E in E_RANGE;
    * mass entries ~ rho h^3 (h^3 from 1e-21 to 1.25e5 m^3): [1e-121, 1.3e105];
    * eigenvalues omega^2 ~ (E / rho) / L^2 for the lowest modes of a body of size L up to
      (E / rho) * 1e16 * 1e3 / h^2 for the highest mode of the mesh: [1e-107, 1e133].

    Each stays more than 20 decades inside 1e+-154, which leaves room for the solver's sums over
    up to 1e8 DOFs and its shift-invert amplification. ``nu`` itself gets no narrower range: the
    factor above is bounded, so it cannot overflow. (How close to 0.5 or -1 the eigen solution
    stays accurate is a conditioning question the eigen certificate answers per problem.)

    Raises:
        MaterialError: a value is not a finite number, outside its physical range, or outside the
            ranges above; the one-line message names the parameter, its value, the range and why.
    """

    E: float
    nu: float
    rho: float
    name: str = ""

    def __post_init__(self) -> None:
        labels = {"E": "Young's modulus E", "nu": "Poisson's ratio nu", "rho": "density rho"}
        for field in ("E", "nu", "rho"):
            value = getattr(self, field)
            try:
                if isinstance(value, bool):
                    raise TypeError
                v = float(value)
            except (TypeError, ValueError, OverflowError):
                raise MaterialError(f"{labels[field]} must be a finite number, got {_show(value)}") from None
            if not math.isfinite(v):
                raise MaterialError(f"{labels[field]} must be a finite number, got {_show(value)}")
            object.__setattr__(self, field, v)
        if self.E <= 0:
            raise MaterialError(f"Young's modulus E must be > 0 Pa, got {self.E:g}")
        if not (-1.0 < self.nu < 0.5):
            raise MaterialError(f"Poisson's ratio nu must lie in (-1, 0.5), got {self.nu:g}")
        if self.rho <= 0:
            raise MaterialError(f"density rho must be > 0 kg/m^3, got {self.rho:g}")
        _in_range("Young's modulus E", "E", self.E, E_RANGE, "Pa")
        _in_range("density rho", "rho", self.rho, RHO_RANGE, "kg/m^3")
        _in_range(
            f"E/rho (E = {self.E:g} Pa, rho = {self.rho:g} kg/m^3)",
            "E/rho",
            self.E / self.rho,
            E_OVER_RHO_RANGE,
            "m^2/s^2",
        )

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


def _show(value) -> str:
    """``repr(value)`` on one line, at most 40 characters (a 400-digit int stays readable)."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 40 else text[:37] + "..."


def _in_range(label: str, key: str, value: float, bounds: tuple[float, float], unit: str) -> None:
    low, high = bounds
    if low <= value <= high:
        return
    way = "overflow" if value > high else "underflow"
    raise MaterialError(
        f"{label} = {value:g} {unit} is outside the range modalfem computes soundly, [{low:g}, {high:g}] {unit}: "
        f"{_WHY[key]} and the eigen solver's squares of them would {way} double precision"
    )


STEEL = Material(E=200e9, nu=0.3, rho=7850.0, name="steel")
ALUMINIUM = Material(E=69e9, nu=0.33, rho=2700.0, name="aluminium")
BRASS = Material(E=100e9, nu=0.34, rho=8500.0, name="brass")
MATERIALS = {m.name: m for m in (STEEL, ALUMINIUM, BRASS)}
