"""Runtime fixtures: a small free steel block as a ModalModel (built once per session, ~0.5 s).

``small_modes`` is (mesh, ModalResult, M) of a free 0.2 x 0.1 x 0.05 m steel box (P1, 4x2x2 hexahedra,
8 deformation modes, scikit-fem + SciPy: no FEniCSx needed); ``small_model`` the ModalModel built
from it with ``ModalModel.from_modes``; ``small_body`` the runtime ``ModalBody``;
``small_coupling`` its ``RotationCoupling`` computed from the assembled mass matrix.
"""

from __future__ import annotations

import numpy as np
import pytest

import modalfem
from modalfem.mesh import box

SIZE = (0.2, 0.1, 0.05)
CELLS = (4, 2, 2)
MODE_COUNT = 8


@pytest.fixture(scope="session")
def small_modes():
    from modalfem.backends.skfem import assemble

    mesh = box(size=SIZE, cells=CELLS)
    res = modalfem.modes(mesh, modalfem.STEEL, k=MODE_COUNT, degree=1, backend="skfem", solver="scipy")
    _, M = assemble(mesh, modalfem.STEEL, degree=1)
    return mesh, res, M


@pytest.fixture(scope="session")
def small_model(small_modes):
    from modalfem.model import ModalModel

    mesh, res, _ = small_modes
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 0.0))


@pytest.fixture()
def small_body(small_model):
    from modalfem.runtime import ModalBody

    return ModalBody(small_model, dtype=np.float64)  # exact reconstruction: tests compare to 1e-14


@pytest.fixture(scope="session")
def small_coupling(small_modes, small_model):
    from modalfem.runtime import RotationCoupling

    _, res, M = small_modes
    return RotationCoupling.from_matrices(res.shapes, M, res.dof_points, small_model.center_of_mass)
