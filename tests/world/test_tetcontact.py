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


def test_two_sided_contacts_and_friction_match_finite_differences():
    """Contacts between two tet bodies (four vertices, signed weights summing to zero, plane at 0) with the lagged
    friction potential: the gradient is the energy's, equal and opposite on the two sides (it sums to zero over
    the vertices), and the Hessian the penalty's plus the friction's positive semi-definite part."""
    rng = np.random.default_rng(1)
    n = 8
    verts = np.array([[0, 4, 5, 6], [1, 5, 6, 7], [2, 3, 6, 7], [0, 1, 7, -1]])
    b = rng.uniform(0.1, 1.0, (4, 3))
    b /= b.sum(1, keepdims=True)
    w = np.column_stack([np.ones(4), -b])
    w[2] = [0.3, 0.7, -0.6, -0.4]  # an edge on an edge
    w[3] = [0.5, 0.5, -1.0, 0.0]  # (a padded column)
    nrm = rng.normal(size=(4, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    x0 = rng.normal(size=(n, 3)) * 0.004
    pen = PenaltyContacts(n)
    pen.set(verts, w, np.zeros((4, 3)), nrm, rng.uniform(1e3, 2e3, 4), 0.004)
    eps = 1e-4
    pen.set_friction(np.arange(4), np.array([2.0, 1.0, 3.0, 0.5]), x0, eps)
    # slips of both kinds: below eps (sticking) and beyond
    x = x0 + rng.normal(size=(n, 3)) * np.array([[3e-5], [3e-5], [3e-5], [3e-5], [2e-3], [2e-3], [2e-3], [3e-5]])
    assert np.count_nonzero(pen.depths(x)) >= 2
    y = pen._slip(x)[1]
    assert (y < eps).any() and (y > eps).any()
    h = 1e-8
    E = [pen.energy((x.ravel() + h * e).reshape(-1, 3)) - pen.energy((x.ravel() - h * e).reshape(-1, 3))
         for e in np.eye(x.size)]
    g = pen.gradient(x, None)
    assert np.allclose(np.array(E) / (2 * h), g.ravel(), rtol=0, atol=1e-6 * np.abs(g).max())
    assert np.abs(g.sum(0)).max() <= 1e-12 * np.abs(g).max()  # equal and opposite on the two sides
    r, c, v = pen.hessian_entries(x, None)
    H = np.zeros((x.size, x.size))
    np.add.at(H, (r, c), v)
    assert np.allclose(H, H.T) and np.linalg.eigvalsh(H).min() >= -1e-9 * np.abs(H).max()
    fric, pen.fric = pen.fric, None  # the penalty's part alone is its exact Hessian
    r, c, v = pen.hessian_entries(x, None)
    Hp = np.zeros((x.size, x.size))
    np.add.at(Hp, (r, c), v)
    Hfd = np.array([pen.gradient((x.ravel() + 1e-9 * e).reshape(-1, 3), None).ravel()
                    - pen.gradient((x.ravel() - 1e-9 * e).reshape(-1, 3), None).ravel() for e in np.eye(x.size)]) / 2e-9
    assert np.allclose(Hp, Hfd, rtol=0, atol=1e-6 * np.abs(Hp).max())
    pen.fric = fric
    assert np.any(H - Hp)  # the friction's part is in the entries
