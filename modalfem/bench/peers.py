"""The two peer recipes the modes benchmark measures against, written the way their users write them.

Both solve the clamped cantilever (clamped at x = 0) for the lowest ``k`` modes on a box of
``size`` [m] split into ``cells`` hexahedra, 6 tetrahedra each, Lagrange degree ``degree``, and
return a dict of wall seconds per stage and the frequencies [Hz]. Neither is tuned: the point is to
measure what the documented recipe costs, side by side with ``modalfem.modes`` in one run.

Peer A, "dolfinx + SLEPc tutorial recipe" (dolfinx 0.5 API), follows:
  * the FEniCSx discourse recipe "Modal analysis using dolfin-x"
    (https://fenicsproject.discourse.group/t/modal-analysis-using-dolfin-x/7349): ``create_box``,
    ``VectorFunctionSpace(mesh, ("CG", p))``, UFL ``inner(sigma(u), epsilon(v)) * dx`` and
    ``rho * inner(u, v) * dx``, ``fem.petsc.assemble_matrix(form, bcs=[bc], diagonal=...)``,
    ``SLEPc.EPS`` with ``ProblemType.GHEP``, ``ST.Type.SINVERT``, ``setFromOptions``;
  * the dolfinx demo ``python/demo/demo_elasticity.py`` for the Lame form and ``locate_dofs_topological``
    on boundary facets, and the ``assemble_matrix`` docstring for ``diagonal`` (value put on the
    diagonal of constrained rows): 1 for K and 0 for M, so constrained DOFs carry an infinite
    eigenvalue that shift-and-invert maps to 0, away from the wanted end;
  * SLEPc defaults otherwise: Krylov-Schur, tolerance 1e-8, ``ncv`` chosen by SLEPc; shift
    sigma = 0 with ``WhichEigenpairs.TARGET_MAGNITUDE``; the ST's KSP is ``preonly`` + LU, here
    with MUMPS as the factorisation package (the usual ``-st_pc_factor_mat_solver_type mumps``).

Peer B, "scikit-fem + SciPy", follows scikit-fem's ``docs/examples/ex03.py`` (linear elastic
eigenvalue problem: ``Basis(mesh, ElementVector(...))`` with the default quadrature,
``skfem.models.elasticity.linear_elasticity(*lame_parameters(E, nu))``, a ``dot(u, v)`` mass form,
``condense(K, M, D=...)`` on the clamped DOFs) with ``scipy.sparse.linalg.eigsh(K, k, M=M,
sigma=0)``, i.e. ARPACK shift-invert on SciPy's default ``splu`` factorisation.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["peer_dolfinx_slepc", "peer_skfem_scipy"]


def peer_dolfinx_slepc(size, cells, degree: int, k: int, E: float, nu: float, rho: float) -> dict:
    """Peer A: dolfinx 0.5 + SLEPc Krylov-Schur, shift-invert at 0, MUMPS LU (tutorial settings).

    Args:
        size: box size (Lx, Ly, Lz) [m]. cells: hexahedra per axis (6 tetrahedra each).
        degree: Lagrange degree. k: modes wanted. E [Pa], nu [-], rho [kg/m^3]: material.

    Returns:
        dict with ``dofs`` (all DOFs, constrained included), ``assembly``, ``eigen``, ``total``
        [s], ``cpu`` (process CPU time, all threads, over ``total``) [s] and ``frequencies_hz`` (the
        lowest ``k``, ascending), ``converged`` (SLEPc count).
    """
    import dolfinx.fem.petsc
    import ufl
    from dolfinx import fem, mesh
    from mpi4py import MPI
    from petsc4py import PETSc
    from slepc4py import SLEPc

    t0, c0 = time.perf_counter(), time.process_time()
    domain = mesh.create_box(
        MPI.COMM_WORLD,
        [np.array([0.0, 0.0, 0.0]), np.array(size, dtype=float)],
        list(cells),
        cell_type=mesh.CellType.tetrahedron,
    )
    V = fem.VectorFunctionSpace(domain, ("CG", degree))

    mu = fem.Constant(domain, PETSc.ScalarType(E / (2.0 * (1.0 + nu))))
    lmbda = fem.Constant(domain, PETSc.ScalarType(E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))))
    dens = fem.Constant(domain, PETSc.ScalarType(rho))

    def epsilon(u):
        return ufl.sym(ufl.grad(u))

    def sigma(u):
        return 2.0 * mu * epsilon(u) + lmbda * ufl.tr(epsilon(u)) * ufl.Identity(len(u))

    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = ufl.inner(sigma(u), epsilon(v)) * ufl.dx
    m = dens * ufl.inner(u, v) * ufl.dx

    fdim = domain.topology.dim - 1
    facets = mesh.locate_entities_boundary(domain, fdim, lambda x: np.isclose(x[0], 0.0))
    dofs = fem.locate_dofs_topological(V, fdim, facets)
    bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)

    K = dolfinx.fem.petsc.assemble_matrix(fem.form(a), bcs=[bc], diagonal=1.0)
    K.assemble()
    M = dolfinx.fem.petsc.assemble_matrix(fem.form(m), bcs=[bc], diagonal=0.0)
    M.assemble()
    t1 = time.perf_counter()

    eps = SLEPc.EPS().create(MPI.COMM_WORLD)
    eps.setOperators(K, M)
    eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps.setDimensions(nev=k)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    eps.setTarget(0.0)
    st = eps.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    st.setShift(0.0)
    ksp = st.getKSP()
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.LU)
    pc.setFactorSolverType("mumps")
    eps.setFromOptions()
    eps.solve()
    nconv = eps.getConverged()
    lam = np.array(sorted(eps.getEigenvalue(i).real for i in range(nconv)))
    t2, c2 = time.perf_counter(), time.process_time()

    n_dofs = V.dofmap.index_map.size_global * V.dofmap.index_map_bs
    return {
        "dofs": int(n_dofs),
        "assembly": t1 - t0,
        "eigen": t2 - t1,
        "total": t2 - t0,
        "cpu": c2 - c0,
        "converged": int(nconv),
        "frequencies_hz": (np.sqrt(np.abs(lam[:k])) / (2 * np.pi)).tolist(),
    }


def peer_skfem_scipy(size, cells, degree: int, k: int, E: float, nu: float, rho: float) -> dict:
    """Peer B: scikit-fem (default quadrature) + ``scipy.sparse.linalg.eigsh(sigma=0)`` (splu).

    Args and returns as ``peer_dolfinx_slepc``.
    """
    import skfem
    from scipy.sparse.linalg import eigsh
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    t0, c0 = time.perf_counter(), time.process_time()
    mesh = skfem.MeshTet.init_tensor(*(np.linspace(0.0, L, n + 1) for L, n in zip(size, cells)))
    elem = skfem.ElementTetP2() if degree == 2 else skfem.ElementTetP1()
    basis = skfem.Basis(mesh, skfem.ElementVector(elem))

    @skfem.BilinearForm
    def mass(u, v, w):
        return rho * dot(u, v)

    K = linear_elasticity(*lame_parameters(E, nu)).assemble(basis)
    M = mass.assemble(basis)
    D = basis.get_dofs(lambda x: np.isclose(x[0], 0.0))
    Kc, Mc, _, _ = skfem.condense(K, M, D=D)
    t1 = time.perf_counter()

    lam, _ = eigsh(Kc, k=k, M=Mc, sigma=0)
    t2, c2 = time.perf_counter(), time.process_time()
    lam = np.sort(lam)
    return {
        "dofs": int(basis.N),
        "assembly": t1 - t0,
        "eigen": t2 - t1,
        "total": t2 - t0,
        "cpu": c2 - c0,
        "converged": len(lam),
        "frequencies_hz": (np.sqrt(np.abs(lam)) / (2 * np.pi)).tolist(),
    }
