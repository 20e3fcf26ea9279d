"""View fixtures: a small free steel block as a ModalModel (scikit-fem + SciPy, ~0.5 s, no FEniCSx)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def view_model():
    import modalfem
    from modalfem.mesh import box
    from modalfem.model import ModalModel

    mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 0.0))


@pytest.fixture(scope="session")
def view_model_file(view_model, tmp_path_factory):
    path = tmp_path_factory.mktemp("view") / "block.npz"
    view_model.save(path)
    return path
