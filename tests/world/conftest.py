"""World fixtures: a small free steel bar as a ModalModel (scikit-fem + SciPy, ~0.5 s, once per session), a soft
tet block and a small cloth."""

from __future__ import annotations

import pytest
from _world import BAR

import modalfem
from modalfem.mesh import box


@pytest.fixture(scope="session")
def bar_model():
    from modalfem.model import ModalModel

    mesh = box(size=BAR, cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))


@pytest.fixture(scope="session")
def block_model():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(0.3, 0.3, 0.1), cells=(3, 3, 2)), Material(E=1e5, nu=0.3, rho=500.0))


@pytest.fixture(scope="session")
def cloth_model():
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothModel
    from modalfem.cloth.scenes import MATERIAL

    return ClothModel(grid((0.4, 0.4), (13, 13), origin=(-0.05, -0.15, 0.0)), MATERIAL, mass_damping=0.1)

