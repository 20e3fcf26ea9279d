"""Pseudo-forces on the modes of a spinning body (Coriolis, centripetal) and the coupling tensors."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.errors import InputError

OMEGA0, SPIN = 10.0, 3.0  # [rad/s]


def _point_oscillator():
    """A body whose 2 modes are the in-plane translations (x, y) of a unit point mass on an isotropic
    spring omega0, at the centre of mass; the body spins about z (symmetric inertia: steady spin).

    Coupling of a unit point mass with Phi = [e_x, e_y]: T[a, b] = Phi_a^T Phi_b, S = 0.
    """
    verts = np.array([[1.0, 0, 0], [0, 1, 0], [-1, -1, 0], [0, 0, 1]]) * 0.1
    shapes = np.tile(np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]), (4, 1))
    model = SimpleNamespace(vertices=verts, triangles=np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]]),
                            shapes=shapes, omega=np.array([OMEGA0, OMEGA0]), mass=1.0, center_of_mass=np.zeros(3),
                            inertia=np.diag([1.0, 1.0, 2.0]), damping=(0.0, 0.0))
    phi = shapes[:3]  # (3, 2): component rows of the point
    T = np.einsum("ai,bj->abij", phi, phi)
    return rt.ModalBody(model), rt.RotationCoupling(T, np.zeros((3, 3, 2)))


def _run(body, effects, spin, t_end=1.2, dt=1e-3):
    solver = rt.ModalSolver(body, effects=effects)
    st = solver.state(angular_velocity=(0.0, 0.0, spin))
    st.q[:] = (1e-3, 0.0)
    t, zeta = [], []
    for i in range(round(t_end / dt)):
        solver.step(st, st, None, None, dt)
        t.append(st.time)
        zeta.append(st.q[0] + 1j * st.q[1])
    return np.array(t), np.array(zeta)


def _fit_residual(t, zeta, freqs):
    """Relative residual of the least-squares fit of zeta(t) by sum_k A_k exp(i f_k t)."""
    E = np.exp(1j * np.outer(t, freqs))
    coef, *_ = np.linalg.lstsq(E, zeta, rcond=None)
    return np.linalg.norm(E @ coef - zeta) / np.linalg.norm(zeta)


def test_coriolis_and_centripetal_split_the_pair_into_omega0_plus_minus_spin():
    """Derivation: in the frame rotating at W about z, the point obeys
    xi'' + 2 W x xi' + W x (W x xi) + omega0^2 xi = 0. With zeta = x + i y this is
    zeta'' + 2 i W zeta' + (omega0^2 - W^2) zeta = 0, roots s = i(-W +- omega0): the rotating-frame
    motion is exactly A e^{i(omega0 - W) t} + B e^{-i(omega0 + W) t} (an isotropic oscillator seen
    from a rotating frame). Without pseudo-forces it stays at +-omega0."""
    body, coupling = _point_oscillator()
    res = [_fit_residual(*_run(body, [rt.PseudoForces(coupling)], SPIN, dt=dt), [OMEGA0 - SPIN, -(OMEGA0 + SPIN)])
           for dt in (2e-3, 1e-3)]
    assert res[1] < 5e-5 and res[0] / res[1] > 3.5  # converges to the theory at second order in dt
    t, zeta = _run(body, [rt.PseudoForces(coupling)], SPIN)
    assert _fit_residual(t, zeta, [OMEGA0, -OMEGA0]) > 0.1  # the shift is real
    t0, zeta0 = _run(body, [], SPIN)
    assert _fit_residual(t0, zeta0, [OMEGA0, -OMEGA0]) < 1e-12


def test_centripetal_alone_softens_the_in_plane_modes_by_spin_squared():
    """Without Coriolis: xi'' + (omega0^2 - W^2) xi = 0 in the plane: each mode at sqrt(omega0^2 - W^2)."""
    body, coupling = _point_oscillator()
    w = np.sqrt(OMEGA0**2 - SPIN**2)
    effects = [rt.PseudoForces(coupling, coriolis=False, euler=False)]
    res = [_fit_residual(*_run(body, effects, SPIN, dt=dt), [w, -w]) for dt in (2e-3, 1e-3)]
    assert res[1] < 5e-5 and res[0] / res[1] > 3.5
    _, zeta = _run(body, effects, SPIN)
    assert np.allclose(zeta.imag, 0.0, atol=1e-15)  # no Coriolis: x and y stay uncoupled


def test_pseudo_forces_change_nothing_without_spin(small_body, small_coupling):
    """With pseudo-forces on, a translating, vibrating body that does not rotate moves exactly as without."""
    states = []
    for effects in ([], [rt.PseudoForces(small_coupling)]):
        solver = rt.ModalSolver(small_body, effects=effects)
        st = solver.state(velocity=(1.0, 2.0, 0.0))
        st.qdot[:] = 0.1
        for _ in range(200):
            solver.step(st, st, None, None, 1e-4)
        states.append(st)
    assert np.array_equal(states[0].q, states[1].q) and np.array_equal(states[0].qdot, states[1].qdot)


def test_pseudo_forces_matter_when_the_real_body_spins(small_body, small_coupling):
    runs = []
    for effects in ([], [rt.PseudoForces(small_coupling)]):
        solver = rt.ModalSolver(small_body, effects=effects)
        st = solver.state(angular_velocity=300.0 * small_body.principal_axes[:, 2])
        st.qdot[:] = 0.1
        for _ in range(200):
            solver.step(st, st, None, None, 1e-5)
        runs.append(st.q.copy())
    assert np.linalg.norm(runs[1] - runs[0]) > 1e-3 * np.linalg.norm(runs[0])


def test_coupling_tensors_of_the_fem_body(small_coupling, small_body):
    T = small_coupling.T
    r = small_body.mode_count
    assert np.allclose(sum(T[a, a] for a in range(3)), np.eye(r), atol=1e-8)  # mass-normalised modes
    for a in range(3):
        for b in range(3):
            assert np.allclose(T[a, b], T[b, a].T, atol=1e-12)  # M symmetric
    G = np.einsum("cde,ceij->dij", rt.effects._EPS, T)
    assert np.allclose(G, -np.transpose(G, (0, 2, 1)), atol=1e-12)  # gyroscopic: antisymmetric
    assert np.abs(G).max() > 0.1  # the modes of a box do couple through the rotation (Coriolis)


def _cross_nodes(w, u):
    """w x u at every node of a node-major vector field u (3 n,) -> (3 n,)."""
    return np.cross(w, u.reshape(-1, 3)).reshape(-1)


def test_coupling_tensors_give_the_kinetic_energy_of_the_rotating_frame(small_modes, small_coupling, small_model):
    """Independent of how T and S are formed: with the full vector mass matrix M and the node fields
    u = Phi q, u' = Phi q' and X (rest positions from the centre of mass), the inertial velocity in
    body axes is u' + w x (X + u), and its kinetic energy 0.5 |.|_M^2 has the cross terms
    u'^T M (w x u) = q'^T G(w) q, |w x u|_M^2 = q^T (|w|^2 I - C(w)) q,
    (w x X)^T M (w x u) = (|w|^2 h0 - h(w)) . q; the Euler load is Phi^T M (w' x X) = s(w').
    (Before this test, T[a, b] with a != b came out zero: M couples equal components only, so
    G(w) - the Coriolis coupling - vanished for every FEM body.)"""
    _, res, M = small_modes
    rng = np.random.default_rng(3)
    T, S = small_coupling.T, small_coupling.S
    eps = rt.effects._EPS
    X = (res.dof_points - small_model.center_of_mass).reshape(-1)
    for _ in range(3):
        w, wdot = rng.normal(size=3) * 5.0, rng.normal(size=3) * 5.0
        q, qd = rng.normal(size=T.shape[2]), rng.normal(size=T.shape[2])
        u, ud = res.shapes @ q, res.shapes @ qd
        G = np.einsum("cde,d,ceij->ij", eps, w, T)
        C = np.einsum("c,e,ceij->ij", w, w, T)
        h = np.einsum("c,e,cei->i", w, w, S)
        h0 = np.einsum("cci->i", S)
        s = np.einsum("cde,d,cei->i", eps, wdot, S)
        wu, wX = _cross_nodes(w, u), _cross_nodes(w, X)
        ref = ud @ (M @ wu)
        assert abs(qd @ G @ q - ref) < 1e-9 * abs(ref)
        assert np.abs(G).max() > 0.05 * np.linalg.norm(w)  # not a vanishing coupling (T[a, b] = O(1))
        assert np.isclose(q @ ((w @ w) * q - C @ q), wu @ (M @ wu), rtol=1e-9)
        assert np.isclose((w @ w) * h0 @ q - h @ q, wX @ (M @ wu), rtol=1e-9)
        f = M @ _cross_nodes(wdot, X)  # (zero projection here: free-body modes are mass-orthogonal to rotations)
        assert np.allclose(s, res.shapes.T @ f, rtol=1e-9, atol=1e-12 * np.abs(res.shapes).max() * np.abs(f).sum())


def test_coupling_of_the_wrong_size_is_refused(small_body):
    with pytest.raises(InputError, match="RotationCoupling"):
        rt.RotationCoupling(np.zeros((3, 3, 2, 2)), np.zeros((3, 3, 3)))
    coupling = rt.RotationCoupling(np.zeros((3, 3, 2, 2)), np.zeros((3, 3, 2)))
    solver = rt.ModalSolver(small_body, effects=[rt.PseudoForces(coupling)])
    st = solver.state(angular_velocity=(0, 0, 1.0))
    with pytest.raises(InputError, match="modes"):
        solver.step(st, st, None, None, 1e-3)


def test_wind_pushes_the_windward_face_with_its_dynamic_pressure(small_body, small_model):
    """Box 0.2 x 0.1 x 0.05 m at rest, wind 10 m/s along +x: only the x = 0 face (0.1 x 0.05 m) is
    windward, F = 0.5 rho C A w^2 along +x; the side faces are parallel (no force), no torque about
    the centre of mass (symmetric), and the modal load is the projection of the vertex forces."""
    rho, C, w = 1.2, 0.9, 10.0
    solver = rt.ModalSolver(small_body, effects=[rt.Wind((w, 0, 0), density=rho, drag=C)])
    st = solver.state()
    loads = rt.Loads(small_body.mode_count)
    solver.effects[0].loads(solver, st, 1e-3, loads)
    assert np.allclose(loads.force, [0.5 * rho * C * 0.1 * 0.05 * w * w, 0, 0], rtol=1e-12, atol=1e-15)
    assert np.allclose(loads.torque, 0.0, atol=1e-15)
    # independent projection: the x = 0 face triangles share their force equally among their vertices
    x = small_model.vertices
    ref = rt.Loads(small_body.mode_count)
    for tri in small_model.triangles:
        if np.allclose(x[tri, 0], 0.0):
            a, b, c = x[tri]
            F = 0.5 * rho * C * 0.5 * np.linalg.norm(np.cross(b - a, c - a)) * w * w * np.array([1.0, 0, 0])
            for v in tri:
                solver.add_point_force(st, int(v), F / 3, ref)
    assert np.allclose(loads.modal, ref.modal, rtol=1e-12, atol=1e-12 * np.abs(ref.modal).max())
    assert np.allclose(ref.force, loads.force, rtol=1e-12)


def test_spinning_fem_body_rings_at_the_gyroscopic_frequencies(small_body, small_coupling):
    """Steady spin W about the principal axis of largest inertia (w' = 0). Body-frame modal equations
    q'' + 2 G q' + (Lam + C - |w|^2 I) q = const, G = Phi^T M [w]x Phi, C = sum w_c w_e T[c, e]: the
    motion is a constant plus sum_k A_k e^{s_k t} over the eigenvalues s_k of the first-order
    system [[0, I], [-(Lam + C - |w|^2 I), -2 G]]. G and C are built here with explicit loops."""
    T, r = small_coupling.T, small_body.mode_count
    axis = small_body.principal_axes[:, 2]
    spin = 0.02 * small_body.omega[0]
    w = spin * axis
    eps = np.zeros((3, 3, 3))
    for (i, j, k), sgn in {(0, 1, 2): 1, (1, 2, 0): 1, (2, 0, 1): 1, (0, 2, 1): -1, (2, 1, 0): -1, (1, 0, 2): -1}.items():
        eps[i, j, k] = sgn
    G = sum(eps[c, d, e] * w[d] * T[c, e] for c in range(3) for d in range(3) for e in range(3))
    C = sum(w[c] * w[e] * T[c, e] for c in range(3) for e in range(3))
    K = np.diag(small_body.omega**2) + C - (w @ w) * np.eye(r)
    s = np.linalg.eigvals(np.block([[np.zeros((r, r)), np.eye(r)], [-K, -2 * G]]))
    assert np.abs(s.real).max() < 1e-6 * np.abs(s).max()  # gyroscopic, undamped: pure oscillation

    def simulate(effects, per_period=40):
        solver = rt.ModalSolver(small_body, effects=effects)
        st = solver.state(angular_velocity=w)
        st.qdot[:] = np.linspace(1.0, 2.0, r)
        dt = 2 * np.pi / small_body.omega[-1] / per_period
        t, q = [], []
        for _ in range(50 * per_period):
            solver.step(st, st, None, None, dt)
            t.append(st.time)
            q.append(st.q.copy())
        return np.array(t), np.array(q)

    def residual(t, q, rates):
        E = np.concatenate([np.exp(np.outer(t, rates)), np.ones((len(t), 1))], axis=1)
        coef, *_ = np.linalg.lstsq(E, q.astype(complex), rcond=None)
        return np.linalg.norm(E @ coef - q) / np.linalg.norm(q)

    static = np.concatenate([1j * small_body.omega, -1j * small_body.omega])
    t, q = simulate([rt.PseudoForces(small_coupling)])
    res = [residual(*simulate([rt.PseudoForces(small_coupling)], 20), s), residual(t, q, s)]
    assert res[1] < 5e-5 and res[0] / res[1] > 3.5  # second-order convergence to the theory
    assert residual(t, q, static) > 100 * res[1]  # the shift is resolved
    t0, q0 = simulate([])
    assert residual(t0, q0, static) < 1e-9


def test_a_model_file_carries_the_coupling_and_pseudo_forces_need_no_argument(small_model, small_coupling, tmp_path):
    """``ModalModel.from_modes`` stores the coupling; ``PseudoForces()`` on the body loaded from the
    file spins exactly like ``PseudoForces(coupling)`` computed in memory, and both ring at the
    gyroscopic frequencies (eigenvalues of the body-frame system built from the in-memory T), not
    at the static ones."""
    assert small_model.rotation_T is not None
    np.testing.assert_allclose(small_model.rotation_T, small_coupling.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(small_model.rotation_S, small_coupling.S, rtol=0, atol=1e-12)
    path = tmp_path / "box.npz"
    small_model.save(path)
    loaded = rt.load(path)
    assert loaded.coupling is not None
    memory = rt.ModalBody(small_model)
    r = memory.mode_count
    w = 0.02 * memory.omega[0] * memory.principal_axes[:, 2]
    T = small_coupling.T
    G = np.einsum("cde,d,ceij->ij", rt.effects._EPS, w, T)
    C = np.einsum("c,e,ceij->ij", w, w, T)
    K = np.diag(memory.omega**2) + C - (w @ w) * np.eye(r)
    rates = np.linalg.eigvals(np.block([[np.zeros((r, r)), np.eye(r)], [-K, -2 * G]]))
    static = np.concatenate([1j * memory.omega, -1j * memory.omega])

    def simulate(body, effect, per_period=40, periods=30):
        solver = rt.ModalSolver(body, effects=[effect])
        st = solver.state(angular_velocity=w)
        st.qdot[:] = np.linspace(1.0, 2.0, r)
        dt = 2 * np.pi / body.omega[-1] / per_period
        t, q = [], []
        for _ in range(periods * per_period):
            solver.step(st, st, None, None, dt)
            t.append(st.time)
            q.append(st.q.copy())
        return np.array(t), np.array(q)

    def residual(t, q, s):
        E = np.concatenate([np.exp(np.outer(t, s)), np.ones((len(t), 1))], axis=1)
        coef, *_ = np.linalg.lstsq(E, q.astype(complex), rcond=None)
        return np.linalg.norm(E @ coef - q) / np.linalg.norm(q)

    t, q_file = simulate(loaded, rt.PseudoForces())
    _, q_mem = simulate(memory, rt.PseudoForces(small_coupling))
    np.testing.assert_allclose(q_file, q_mem, rtol=0, atol=1e-10 * np.abs(q_mem).max())
    fit = residual(t, q_file, rates)
    assert fit < 5e-5 and residual(t, q_file, static) > 100 * fit


def test_pseudo_forces_without_any_coupling_are_refused(small_model):
    from types import SimpleNamespace

    fields = {k: getattr(small_model, k) for k in ("vertices", "triangles", "shapes", "omega", "mass",
                                                    "center_of_mass", "inertia", "damping")}
    body = rt.ModalBody(SimpleNamespace(**fields))  # an old model: no rotation tensors
    assert body.coupling is None
    solver = rt.ModalSolver(body, effects=[rt.PseudoForces()])
    st = solver.state(angular_velocity=(0, 0, 1.0))
    with pytest.raises(InputError, match="rotation coupling"):
        solver.step(st, st, None, None, 1e-3)
    with pytest.raises(InputError, match="RotationCoupling or None"):
        rt.PseudoForces(np.zeros((3, 3, 2, 2)))
