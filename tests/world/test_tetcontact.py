"""``world.tetcontact.PenaltyContacts`` with moving bodies eliminated: its energy, gradient and Hessian (sparse part
minus the low-rank part) agree with finite differences, and the body displacement it solves for is the minimiser."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.world.tetcontact import PenaltyContacts


@pytest.fixture
def contacts():
    rng = np.random.default_rng(0)
    n, c = 6, 6
    verts = np.array([[0, 1, 2], [3, -1, -1], [4, 5, -1], [1, -1, -1], [2, 3, 4], [5, -1, -1]])
    w = np.where(verts >= 0, rng.uniform(0.2, 1.0, (c, 3)), 0.0)
    w /= w.sum(1, keepdims=True)
    nrm = rng.normal(size=(c, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    arms = np.column_stack([nrm, np.cross(rng.normal(size=(c, 3)) * 0.05, nrm)])
    S = [np.diag([1e3, 1e3, 1e3, 2.0, 3.0, 4.0]), np.diag([5e2, 5e2, 5e2, 1.0, 1.0, 2.0])]
    pen = PenaltyContacts(n)
    # depths of a few mm: some contacts in the smooth onset (below SMOOTH * dhat), some beyond, one obstacle
    pen.set(verts, w, rng.normal(size=(c, 3)) * 0.004, nrm, rng.uniform(1e3, 2e3, c), 0.004,
            bodies=np.array([0, 0, -1, 1, 0, 1]), arms=arms, inertia=S)
    return pen, rng.normal(size=(n, 3)) * 0.004


def test_gradient_and_hessian_match_finite_differences(contacts):
    pen, x = contacts
    assert np.count_nonzero(pen.depths(x)) >= 3
    h = 1e-7
    E = [pen.energy((x.ravel() + h * e).reshape(-1, 3), None) - pen.energy((x.ravel() - h * e).reshape(-1, 3), None)
         for e in np.eye(x.size)]
    g = pen.gradient(x, None).ravel()
    assert np.allclose(np.array(E) / (2 * h), g, rtol=0, atol=1e-6 * np.abs(g).max())
    r, c, v = pen.hessian_entries(x, None)
    H = np.zeros((x.size, x.size))
    np.add.at(H, (r, c), v)
    V, S = pen.hessian_low_rank(x, None)
    H -= V @ np.linalg.solve(S, V.T)
    Hfd = np.array([pen.gradient((x.ravel() + h * e).reshape(-1, 3), None).ravel()
                    - pen.gradient((x.ravel() - h * e).reshape(-1, 3), None).ravel() for e in np.eye(x.size)]) / (2 * h)
    # the onset's third derivative jumps by k / e at depth e: a central difference across it errs by up to h k / e
    kink = h * float(pen.k.max()) / float(pen.eps[pen.eps > 0].min())
    assert np.allclose(H, Hfd, rtol=0, atol=1e-6 * np.abs(H).max() + kink)


def test_the_bodies_displacements_minimise_the_energy(contacts):
    pen, x = contacts
    E = pen.energy(x, None)
    u = [a.copy() for a in pen.u]
    rng = np.random.default_rng(1)
    for _ in range(20):  # any other displacement of the bodies costs more
        pen.u = [a + rng.normal(size=6) * 1e-4 for a in u]
        d = pen.dhat - np.einsum("cd,cd->c", np.einsum("cj,cjd->cd", pen.w, x[pen.vid]) - pen.p, pen.nrm)
        z = d + np.array([pen.arms[c] @ pen.u[b] if b >= 0 else 0.0 for c, b in enumerate(pen.bodies)])
        from modalfem.world.tetcontact import _psi

        other = float(_psi(z, pen.k, pen.eps)[0].sum()) + sum(0.5 * a @ S @ a for a, S in zip(pen.u, pen.inertia))
        assert other >= E
