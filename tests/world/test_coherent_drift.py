"""The coherent pair search's motion bound (``_coherent_kernels._drift``): the largest move of a point within ``size``
of a body's centre when its axes in the other body's go from (M0, t0) to (M, t) is ``max |(M - M0) x + t - t0|``
over ``|x| <= size``, at most ``||M - M0||_2 size + |t - t0|``. The bound must never be below that (else a walk would
be reused when features came within reach) and, for a change of rotation, is below the Frobenius-norm bound it
replaced: for a turn by theta, ``||M - M0||_F = 2 sqrt(2) sin(theta/2)``, the spectral norm ``2 sin(theta/2)`` and the
bound ``2 sqrt(4/3) sin(theta/2)`` (Laguerre-Samuelson on the eigenvalues of A^T A), so bound / Frobenius = sqrt(2/3)
within the bound's rounding allowance (1e-7 of ||A||_F^2 under the root).
"""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.world import _coherent_kernels as CK


def _rotation(axis, angle):
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.mark.parametrize("seed", range(5))
def test_drift_bounds_the_largest_move_and_is_below_the_frobenius_bound_for_turns(seed):
    rng = np.random.default_rng(seed)
    for _ in range(400):
        M0 = _rotation(rng.normal(size=3), rng.uniform(0, np.pi))
        angle = 10.0 ** rng.uniform(-8, 0.5)
        M = M0 @ _rotation(rng.normal(size=3), angle)
        t0, t = rng.normal(size=3), rng.normal(size=3) * 10.0 ** rng.uniform(-6, 0)
        size = rng.uniform(0.01, 1.0)
        got = CK._drift(M.reshape(-1), t, M0.reshape(-1), t0, size)
        A = M - M0
        true = np.linalg.norm(A, 2) * size + np.linalg.norm(t - t0)
        assert got >= true * (1 - 1e-12)
        fro = np.linalg.norm(A) * size + np.linalg.norm(t - t0)
        rot = got - np.linalg.norm(t - t0)
        # sqrt(2/3) of the Frobenius term, the allowance sqrt(1e-7) relative at most
        assert rot <= np.linalg.norm(A) * size * (np.sqrt(2 / 3) + 4e-4) + 1e-15
        assert got <= fro * (1 + 1e-12)
    for _ in range(400):  # any matrices (not rotations): still a bound
        M0, M = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
        got = CK._drift(M.reshape(-1), np.zeros(3), M0.reshape(-1), np.zeros(3), 1.0)
        assert got >= np.linalg.norm(M - M0, 2) * (1 - 1e-12)
