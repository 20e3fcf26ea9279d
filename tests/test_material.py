"""Material validation: physical ranges and the range of E, rho and E/rho computed soundly."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from modalfem.errors import MaterialError
from modalfem.material import E_OVER_RHO_RANGE, E_RANGE, RHO_RANGE, STEEL, Material

# one ulp inside / outside the documented bounds [1e-100, 1e100] (written out, not read from the module)
LOW, HIGH = 1e-100, 1e100
INSIDE_LOW, INSIDE_HIGH = math.nextafter(LOW, 1.0), math.nextafter(HIGH, 0.0)
OUTSIDE_LOW, OUTSIDE_HIGH = math.nextafter(LOW, 0.0), math.nextafter(HIGH, math.inf)


def test_documented_ranges():
    assert E_RANGE == RHO_RANGE == E_OVER_RHO_RANGE == (LOW, HIGH)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"E": LOW, "rho": LOW},  # E/rho = 1
        {"E": HIGH, "rho": HIGH},
        {"E": INSIDE_HIGH, "rho": 1.0},
        {"E": INSIDE_LOW, "rho": 1.0},
        {"E": 1.0, "rho": INSIDE_HIGH},
        {"E": 1.0, "rho": INSIDE_LOW},
        {"E": 1e50, "rho": 1e-49},  # E/rho = 1e99, near the edge
        {"E": 1e-49, "rho": 1e50},
        {"E": 1.0, "rho": 1.0},  # non-dimensional use
        {"E": 1e3, "rho": 1.0},  # soft gel ... diamond
        {"E": 1.2e12, "rho": 3500.0},
    ],
)
def test_values_inside_the_range_construct(kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = Material(nu=0.3, **kwargs)
    assert (m.E, m.rho) == (kwargs["E"], kwargs["rho"])


@pytest.mark.parametrize("nu", [-1 + 2.3e-16, -0.9999999999, 0.0, 0.4999999999, math.nextafter(0.5, 0.0)])
def test_nu_is_only_limited_to_its_open_physical_interval(nu):
    m = Material(E=HIGH, nu=nu, rho=1.0)  # the largest E with the most extreme nu still constructs
    assert m.nu == nu
    assert math.isfinite(m.lame_lambda) and math.isfinite(m.shear_modulus)


OUT_OF_RANGE = [
    ({"E": 1e308}, r"Young's modulus E = 1e\+308 Pa .*\[1e-100, 1e\+100\] Pa: .*overflow"),
    ({"E": 1e-300}, r"Young's modulus E = 1e-300 Pa .*\[1e-100, 1e\+100\] Pa: .*underflow"),
    ({"E": 5e-324}, r"Young's modulus E = 4\.94066e-324 Pa .*underflow"),  # subnormal
    ({"E": OUTSIDE_HIGH}, r"Young's modulus E = 1e\+100 Pa .*overflow"),
    ({"E": OUTSIDE_LOW}, r"Young's modulus E = 1e-100 Pa .*underflow"),
    ({"rho": 1e308}, r"density rho = 1e\+308 kg/m\^3 .*\[1e-100, 1e\+100\] kg/m\^3: .*overflow"),
    ({"rho": 1e-300}, r"density rho = 1e-300 kg/m\^3 .*underflow"),
    ({"rho": OUTSIDE_HIGH}, r"density rho .*overflow"),
    ({"rho": OUTSIDE_LOW}, r"density rho .*underflow"),
    ({"E": 1e60, "rho": 1e-60}, r"E/rho .* = 1e\+120 m\^2/s\^2 .*\[1e-100, 1e\+100\] m\^2/s\^2: eigenvalues.*overflow"),
    ({"E": 1e-60, "rho": 1e60}, r"E/rho .* = 1e-120 m\^2/s\^2 .*underflow"),
    ({"E": HIGH, "rho": 0.5}, r"E/rho .*overflow"),
]


@pytest.mark.parametrize("kwargs, match", OUT_OF_RANGE)
def test_out_of_range_is_one_line_error_without_warnings(kwargs, match):
    p = {"E": 1.0, "nu": 0.3, "rho": 1.0, **kwargs}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning (overflow, divide) on the way
        with pytest.raises(MaterialError, match=match) as info:
            Material(**p)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "field, value",
    [
        ("E", math.inf), ("E", -math.inf), ("E", math.nan), ("E", 10**400), ("E", "stiff"), ("E", None), ("E", True),
        ("rho", math.inf), ("rho", math.nan), ("rho", 10**400), ("rho", [1.0]),
        ("nu", math.nan), ("nu", math.inf), ("nu", 10**400), ("nu", False),
    ],
)
def test_not_a_finite_number(field, value):
    p = {"E": 200e9, "nu": 0.3, "rho": 7850.0, field: value}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MaterialError, match=rf"{field} must be a finite number, got ") as info:
            Material(**p)
    text = str(info.value)
    assert "\n" not in text and len(text) < 120  # a 400-digit int is shortened


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"E": 0.0}, "Young's modulus E must be > 0 Pa"),
        ({"E": -1e308}, "Young's modulus E must be > 0 Pa"),
        ({"rho": 0.0}, "density rho must be > 0"),
        ({"rho": -7850.0}, "density rho must be > 0"),
        ({"nu": -1.0}, r"Poisson's ratio nu must lie in \(-1, 0.5\)"),
        ({"nu": 0.5}, r"Poisson's ratio nu must lie in \(-1, 0.5\)"),
        ({"nu": -1.5}, r"Poisson's ratio nu must lie in \(-1, 0.5\)"),
    ],
)
def test_physical_ranges(kwargs, match):
    with pytest.raises(MaterialError, match=match):
        Material(**{"E": 200e9, "nu": 0.3, "rho": 7850.0, **kwargs})


def test_numpy_scalars_become_floats():
    m = Material(E=np.float32(2e11), nu=np.float64(0.3), rho=np.int64(7850))
    assert type(m.E) is float and type(m.rho) is float and m.rho == 7850.0
    assert STEEL.wave_speed == pytest.approx(math.sqrt(200e9 / 7850.0), rel=1e-15)


@pytest.mark.parametrize("E, rho", [(HIGH, 1.0), (1.0, LOW), (LOW, 1.0), (1.0, HIGH), (HIGH, HIGH), (LOW, LOW)])
def test_modes_at_the_range_corners_obey_the_scaling_law(E, rho):
    """omega scales as sqrt(E / rho) exactly; at the corners of the range the solve is still certified."""
    import modalfem
    from modalfem.mesh import box

    mesh = box(size=(1.0, 0.2, 0.2), cells=(4, 1, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        ref = modalfem.modes(mesh, Material(E=1.0, nu=0.3, rho=1.0), k=3, degree=1, fixed="x0", backend="skfem")
        res = modalfem.modes(mesh, Material(E=E, nu=0.3, rho=rho), k=3, degree=1, fixed="x0", backend="skfem")
    assert ref.certificate.passed and res.certificate.passed
    np.testing.assert_allclose(res.omega, ref.omega * math.sqrt(E / rho), rtol=1e-8)
