"""Backend-test helpers: backend parametrisation and loading (meshgen holds the test meshes)."""

import pytest

#: backends to parametrise physics tests over; FEniCSx ones are marked and skipped when missing
BACKEND_PARAMS = ["skfem", pytest.param("fenicsx", marks=pytest.mark.fenicsx)]


def load_backend(name: str):
    """The backend module, skipping the test when FEniCSx is requested but not installed."""
    if name == "fenicsx":
        pytest.importorskip("dolfinx")
    from modalfem.backends import get_backend

    return get_backend(name)
