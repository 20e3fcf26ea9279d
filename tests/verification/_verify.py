"""Helpers for the verification suite: backend parametrisation and cached solves (imported as ``_verify``)."""

from __future__ import annotations

import functools

import pytest

import modalfem
from modalfem.backends import have_fenicsx

BACKENDS = [
    pytest.param("skfem", id="skfem"),
    pytest.param(
        "fenicsx",
        id="fenicsx",
        marks=[pytest.mark.fenicsx, pytest.mark.skipif(not have_fenicsx(), reason="FEniCSx not installed")],
    ),
]


@functools.lru_cache(maxsize=32)
def solve_box(size: tuple, cells: tuple, *, backend: str, k: int, fixed=None, degree: int = 2):
    """modes() of a steel box mesh; cached so several tests share one solve per backend."""
    from modalfem.mesh import box

    mesh = box(size=size, cells=cells)
    res = modalfem.modes(mesh, modalfem.STEEL, k=k, degree=degree, fixed=fixed, backend=backend)
    # Accuracy is what this suite checks; the certificate itself is tested with modes(). A residual
    # of 1e-6 moves a frequency by ~1e-12 relative; on slender beams the roundoff floor of the residual
    # itself is ~1e-5 (certify.FLOOR_FACTOR), so a tenth of it is as good as double precision allows.
    # missed_count == 0 means no mode below the top one was skipped, so label lookups see the true
    # lowest modes.
    assert res.certificate.missed_count == 0
    assert res.certificate.max_residual < max(1e-6, 0.1 * res.info["residual_floor"])
    return res


def by_label(res) -> dict[str, float]:
    """label -> frequency [Hz] (the lowest mode carrying that label)."""
    out: dict[str, float] = {}
    for label, f in zip(res.labels, res.frequencies_hz):
        out.setdefault(label, float(f))
    return out


def rel(a: float, b: float) -> float:
    return a / b - 1.0


__all__ = ["BACKENDS", "by_label", "rel", "solve_box"]
