"""``modes``: the lowest certified vibration modes of a meshed elastic body.

Pipeline: constraints -> assembly (FEniCSx or scikit-fem) -> restriction to free DOFs -> automatic
negative shift -> eigen solve (block Krylov-Schur, SLEPc or ARPACK) -> rigid/deformation split ->
certificate -> labels.

The shift (no user input) is ``modalfem.eigen.shift.estimate_shift``.

Rigid modes come from the mesh's structure, not from eigenvalues (``modalfem.eigen.rigid``): the
zero-energy fields (rigid per piece, and any hinge a piece has) are known exactly, every solver
works in their M-orthogonal complement, and they are returned as the rigid modes. The certificate
checks that the elastic modes are M-orthogonal to them (``Certificate.rigid_coupling``).
"""

from __future__ import annotations

import contextlib
import sys
import time
import warnings
from dataclasses import replace

import numpy as np

from modalfem.errors import (
    BackendUnavailableError,
    InputError,
    ModalfemError,
    SolverError,
)
from modalfem.result import ModalResult

__all__ = ["SOLVERS", "modes"]

SOLVERS = ("block", "slepc", "scipy")


def restrict(A, keep: np.ndarray):
    """A[keep][:, keep] as CSR with sorted indices, in one vectorised pass over the entries (scipy's
    two fancy-indexing passes cost ~0.3 s at 11M entries).

    Args:
        A: square scipy sparse matrix (n, n).
        keep: boolean mask (n,) of the rows and columns kept.
    """
    import scipy.sparse as sp

    A = sp.csr_matrix(A)
    keep = np.asarray(keep, dtype=bool)
    new = np.cumsum(keep) - 1
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    sel = keep[rows] & keep[A.indices]
    r = new[rows[sel]]
    m = int(keep.sum())
    indptr = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=m), out=indptr[1:])
    out = sp.csr_matrix((A.data[sel], new[A.indices[sel]], indptr), shape=(m, m))
    if not A.has_sorted_indices:
        out.sort_indices()
    return out


def _residual_floor(K_ff, X: np.ndarray, rows, comm) -> np.ndarray:
    """sqrt(r) eps || |K| |x| || / ||K x|| per column: the roundoff floor of the relative residual.

    r is the most nonzeros in a row of K; sqrt(r) u |K| |x| bounds the rounding error of the product
    K x with high probability (Higham and Mary 2019), so no solver can certify residuals below it.
    """
    if rows is None:
        from modalfem.eigen.scipy_solver import residual_floor

        return residual_floor(K_ff, X)
    import scipy.sparse as sp
    from mpi4py import MPI

    all_rows = np.concatenate(comm.allgather(np.asarray(rows)))  # PETSc global index -> canonical free index
    indptr, indices, data = K_ff.getValuesCSR()
    Kl = sp.csr_matrix((data, indices, indptr), shape=(len(rows), len(all_rows)))
    r = comm.allreduce(int(np.max(np.diff(indptr))) if len(indptr) > 1 else 0, op=MPI.MAX)
    eps = np.finfo(float).eps * np.sqrt(r)
    Xg = X[all_rows]
    num = comm.allreduce(np.sum((abs(Kl) @ np.abs(Xg)) ** 2, axis=0), op=MPI.SUM)
    den = comm.allreduce(np.sum((Kl @ Xg) ** 2, axis=0), op=MPI.SUM)
    return eps * np.sqrt(num) / np.maximum(np.sqrt(den), np.finfo(float).tiny)


def _versions(backend: str, solver: str) -> dict:
    import numpy
    import scipy

    v = {"numpy": numpy.__version__, "scipy": scipy.__version__}
    for mod, key in (("skfem", "scikit-fem"), ("dolfinx", "dolfinx"), ("petsc4py", "petsc4py"), ("slepc4py", "slepc4py")):
        if mod in sys.modules:
            v[key] = getattr(sys.modules[mod], "__version__", "?")
    return v


def _validate(mesh, material, k, degree, tol):
    from modalfem.material import Material
    from modalfem.mesh.core import Mesh

    if not isinstance(mesh, Mesh):
        raise InputError(f"mesh must be a modalfem Mesh, got {type(mesh).__name__}")
    if not isinstance(material, Material):
        raise InputError(f"material must be a modalfem Material, got {type(material).__name__}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise InputError(f"k must be an integer >= 1 (number of deformation modes), got {k!r}")
    if isinstance(degree, bool) or degree not in (1, 2):
        raise InputError(f"degree must be 1 or 2, got {degree!r}")
    if not (isinstance(tol, (int, float)) and 0 < tol < 1):
        raise InputError(f"tol must be a relative residual in (0, 1), got {tol!r}")


def _pick_solver(solver: str) -> str:
    """``"auto"``: SLEPc for a distributed run (``mpirun -n N``, N > 1); else the block Krylov-Schur on a
    PARDISO factor where MKL loads (measured at 139,587 DOFs: 52 solves in blocks of 4 took 3.2 s
    against 9.3 s for SLEPc's 44 single solves in the same conditions); else SLEPc (MUMPS) if installed;
    else SciPy's ARPACK."""
    from modalfem.backends import have_slepc

    if solver == "auto":
        if have_slepc() and _world_size() > 1:
            return "slepc"
        if _have_pardiso():
            return "block"
        return "slepc" if have_slepc() else "scipy"
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; choose one of: auto, {', '.join(SOLVERS)}")
    if solver == "slepc" and not have_slepc():
        raise BackendUnavailableError(
            "solver 'slepc' needs Debian's python3-slepc4py and python3-petsc4py seen from a venv built "
            "with --system-site-packages (run `make setup` as root), or use solver='scipy'"
        )
    return solver


def _world_size() -> int:
    from mpi4py import MPI

    return int(MPI.COMM_WORLD.size)


def _mpi_comm(backend: str, solver: str):
    """COMM_WORLD when running distributed (size > 1) with FEniCSx + SLEPc, else None."""
    if backend != "fenicsx" or solver != "slepc":
        return None
    from mpi4py import MPI

    return MPI.COMM_WORLD if MPI.COMM_WORLD.size > 1 else None


def _solve(solver, K_ff, M_ff, *, nev, shift, tol, rows, comm, say, groups=None, deflate=None, unit=1.0):
    """One eigen solve of the lowest ``nev`` pairs, the ``deflate`` fields (n_free, r) first; ``groups``
    = the node of each free DOF (serial: PARDISO orders the node graph, a third of the DOF graph);
    ``unit`` [rad^2/s^2] = one eigenvalue unit of the scaled pencil (for the progress line only)."""
    say(f"eigen ({solver}, nev={nev}, shift={shift * unit:.4g} rad^2/s^2)")
    if comm is None and _have_pardiso():  # PARDISO's MKL threads own the cores (see eigen.blas_threads)
        from modalfem.eigen.blas_threads import one_openblas_thread

        limit = one_openblas_thread()
    else:
        limit = contextlib.nullcontext()
    with limit:
        try:
            n = K_ff.getSize()[0] if comm is not None else K_ff.shape[0]
            if solver == "slepc" and (comm is not None or nev + 2 < n):
                from modalfem.eigen.slepc import solve_slepc

                kw = {"rows": rows, "comm": comm} if comm is not None else {"groups": groups}
                return solve_slepc(K_ff, M_ff, nev=nev, shift=shift, tol=tol, deflate=deflate, **kw)
            from modalfem.eigen.scipy_solver import solve_scipy

            # (a tiny problem whose k reaches every mode goes to the dense path whichever solver was asked)
            method = "block" if solver == "block" else "arpack"
            return solve_scipy(K_ff, M_ff, nev=nev, shift=shift, tol=tol, groups=groups, method=method, deflate=deflate)
        except (ModalfemError, ImportError):
            raise
        except Exception as exc:  # noqa: BLE001 - never a raw ARPACK/PETSc traceback
            raise SolverError(f"{solver} eigen solve failed: {type(exc).__name__}: {exc}") from None


def _small_blas(n_free: int, comm):
    """OpenBLAS on one thread for the dense work of a small serial problem (below PARDISO's one-thread
    size, ``modalfem.eigen.pardiso.SERIAL_BELOW``): its products are too small to share, and on a busy
    machine a second OpenBLAS thread that has to wait for a core made the same block Krylov-Schur run
    take 0.82-0.94 s instead of 0.15-0.22 s in 2 of 8 runs (3,000 DOFs, load ~8 on 2 cores; on one
    thread: 0.15-0.18 s in all 8)."""
    from modalfem.eigen.pardiso import SERIAL_BELOW

    if comm is not None or n_free >= SERIAL_BELOW:
        return contextlib.nullcontext()
    from modalfem.eigen.blas_threads import one_openblas_thread

    return one_openblas_thread()


def _have_pardiso() -> bool:
    from modalfem.eigen.pardiso import have_pardiso

    return have_pardiso()


def _missed(raw) -> int:
    """Eigenvalues the solve missed below the inertia shift: Sylvester count minus computed below it."""
    lam = np.asarray(raw.eigenvalues, dtype=float)
    return max(int(raw.inertia_count) - int(np.sum(lam < raw.inertia_shift)), 0)


def _labels(points, shapes, pieces=None) -> tuple[str, ...]:
    from modalfem.eigen.labels import label_modes

    try:
        return tuple(label_modes(points, shapes, pieces=pieces))
    except Exception as exc:  # noqa: BLE001 - labels are cosmetic: never lose a certified solve over them
        warnings.warn(f"mode labelling failed ({type(exc).__name__}: {exc}); using 'mode i'", stacklevel=3)
        return tuple(f"mode {i + 1}" for i in range(shapes.shape[1]))


def modes(
    mesh,
    material,
    *,
    k: int,
    degree: int = 2,
    fixed=None,
    backend: str = "auto",
    solver: str = "auto",
    lumped: bool = False,
    tol: float = 1e-10,
    progress=None,
) -> ModalResult:
    """Lowest ``k`` deformation modes (and all rigid-body modes) of a body, with a certificate.

    Args:
        mesh: the tetrahedral ``Mesh`` [m].
        material: isotropic ``Material`` (E [Pa], nu, rho [kg/m^3]).
        k: number of deformation (non-rigid) modes, >= 1.
        degree: Lagrange degree, 1 or 2.
        fixed: held DOFs: None (free body), a tag name, a predicate ``p (n, 3) -> bool (n,)``, a
            ``Fix(where, components=...)``, or a list of those (see ``modalfem.constraints``).
        backend: ``"auto"`` (FEniCSx if installed, else scikit-fem), ``"fenicsx"`` or ``"skfem"``.
        solver: ``"auto"`` (see ``_pick_solver``: the block solver on PARDISO in one process, SLEPc
            under MPI), ``"block"`` (block Krylov-Schur, ``modalfem.eigen.block``), ``"slepc"``
            (SLEPc Krylov-Schur) or ``"scipy"`` (ARPACK).
        lumped: use a lumped (diagonal) mass matrix.
        tol: bound on the relative residuals ||K x - lambda M x|| / ||K x|| for the certificate.
        progress: optional callable(str), called with a short message at each stage.

    Returns:
        ``ModalResult`` with omega [rad/s] ascending, mass-normalised shapes over all DOFs (zeros at
        fixed DOFs), rigid shapes, labels, certificate, timings [s] and provenance ``info``.

    Raises:
        InputError: bad argument types/values. ConstraintError: bad ``fixed``.
        SolverError: k exceeds the free DOFs, or the eigen solve failed.
        BackendUnavailableError: the requested backend/solver is not installed.
    """
    from modalfem.backends import get_backend, resolve_backend
    from modalfem.constraints import fixed_mask
    from modalfem.eigen.certify import build_certificate
    from modalfem.eigen.rigid import analyse_rigid, node_pieces
    from modalfem.eigen.shift import estimate_shift

    say = progress if callable(progress) else (lambda msg: None)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    _validate(mesh, material, k, degree, tol)
    k = int(k)
    backend = resolve_backend(backend)
    solver = _pick_solver(solver)

    say("constraints")
    t = time.perf_counter()
    fixed = fixed_mask(mesh, degree, fixed)
    free = ~fixed
    n_free = int(free.sum())
    structure = analyse_rigid(mesh, degree, fixed)
    r = structure.zero_energy_count  # rigid modes, plus the hinges of a mechanism (reported below)
    timings["constraints"] = time.perf_counter() - t
    if k > n_free - r:
        # one rule: a body has n_free - r deformation modes; the last of them is certified by placing the
        # inertia shift above the whole spectrum (every eigenvalue computed), so k may reach it
        raise SolverError(
            f"k={k} exceeds the {max(n_free - r, 0)} deformation modes this mesh has ({n_free} free DOFs "
            f"minus {r} rigid): ask for at most {max(n_free - r, 0)} modes or refine the mesh"
        )
    nev = k + r

    comm = _mpi_comm(backend, solver)
    say(f"assembly ({backend}, P{degree}, {3 * mesh.node_count(degree)} DOFs{', distributed' if comm else ''})")
    t = time.perf_counter()
    rows = None
    mod = get_backend(backend)
    if comm is not None:
        K_ff, M_ff, rows = mod.assemble_petsc(mesh, material, degree=degree, free=free, lumped=lumped, comm=comm)
    elif hasattr(mod, "assemble_free"):  # the backend restricts while it converts (less data movement)
        K_ff, M_ff = mod.assemble_free(mesh, material, degree=degree, free=free, lumped=lumped)
    else:
        K, M = mod.assemble(mesh, material, degree=degree, lumped=lumped)
        K_ff, M_ff = restrict(K, free), restrict(M, free)
        del K, M
    timings["assembly"] = time.perf_counter() - t
    # the pencil is solved in units where M's largest diagonal entry is 1 and the Ritz bound of lambda_1
    # is 1 (eigenvectors unchanged up to 1/sqrt(b), eigenvalues in units of theta). PARDISO compares pivots
    # with a fixed 1e-8: a 0.1 mm box with E = 1e-12 Pa (entries ~1e-17) gave frequencies 10x off; in
    # these units the pivots of K - shift M are >= ~1 whatever the body's size and material.
    b = _diagonal_max(M_ff, comm)
    _scale(K_ff, 1.0 / b)
    _scale(M_ff, 1.0 / b)

    say("shift")
    t = time.perf_counter()
    with _small_blas(n_free, comm):
        Z = structure.basis(free, M_ff, rows=rows, comm=comm)
        shift, theta = estimate_shift(mesh, degree, fixed, K_ff, M_ff, rigid_count=r, rows=rows, comm=comm,
                                      deflate=Z)
    unit = theta  # [rad^2/s^2] per eigenvalue unit of the solved pencil
    _scale(K_ff, 1.0 / unit)
    shift = shift / unit
    timings["shift"] = time.perf_counter() - t

    t = time.perf_counter()
    groups = np.flatnonzero(free) // 3 if comm is None else None  # node of each free DOF
    raw = _solve(solver, K_ff, M_ff, nev=nev, shift=shift, tol=tol, rows=rows, comm=comm, say=say, groups=groups,
                 deflate=Z, unit=unit)
    missed = _missed(raw)
    if missed > 0 and nev + missed + 4 <= n_free - 1:
        # a Krylov solver can miss copies of a multiple eigenvalue: the Sylvester count says how many;
        # one retry with a wider search usually recovers them
        say(f"retry: {missed} eigenvalue(s) missed below the inertia shift")
        raw = _solve(solver, K_ff, M_ff, nev=nev + missed + 4, shift=shift, tol=tol, rows=rows, comm=comm, say=say,
                     groups=groups, deflate=Z, unit=unit)
    timings["eigen"] = time.perf_counter() - t
    for key, val in raw.timings.items():
        timings[f"eigen.{key}"] = float(val)

    say("certificate")
    t = time.perf_counter()
    lam = np.asarray(raw.eigenvalues, dtype=float)
    X = np.asarray(raw.vectors)
    if len(lam) < r + k:
        raise SolverError(f"the eigen solve returned {len(lam)} pairs, fewer than the {r} rigid + k={k} wanted")
    if "residual_floor" in raw.info and len(raw.info["residual_floor"]) == len(lam):
        floor = np.asarray(raw.info["residual_floor"], dtype=float)  # the solver computed it already
    else:
        floor = _residual_floor(K_ff, X, rows, comm)
    coupling = _rigid_coupling(Z, X[:, r : r + k], M_ff, rows, comm)
    cert = build_certificate(raw, r, r + k, tol=tol, keep=k, residual_floor=floor, rigid_coupling=coupling)
    cert = replace(cert, inertia_shift=cert.inertia_shift * unit)
    lam, X, shift = lam * unit, X / np.sqrt(b), shift * unit
    if structure.mechanisms:
        cert = replace(cert, passed=False)
        warnings.warn(
            f"mechanism: {'; '.join(structure.mechanisms)} ({r} zero-frequency modes where {structure.rigid_count} "
            "rigid ones were expected); certificate failed",
            RuntimeWarning,
            stacklevel=2,
        )
    timings["certificate"] = time.perf_counter() - t

    n_dof = fixed.size
    shapes = np.zeros((n_dof, k))
    shapes[free] = X[:, r : r + k]
    rigid_shapes = np.zeros((n_dof, r))
    rigid_shapes[free] = X[:, :r]
    lam_def = lam[r : r + k]
    if np.any(lam_def <= 0):
        raise SolverError(
            f"deformation eigenvalue {lam_def.min():.3g} rad^2/s^2 is not positive: K is not positive definite "
            "off the rigid motions (check the material: nu close to 0.5 makes K too ill-conditioned)"
        )
    points = mesh.dof_points(degree)

    say("labels")
    t = time.perf_counter()
    with _small_blas(n_free, comm):
        labels = _labels(points, shapes, node_pieces(mesh, degree))
    timings["labels"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    say(f"done: certificate {'passed' if cert.passed else 'FAILED'}")
    info = {
        "shift": float(shift),
        "shift_ritz_bound": float(theta),
        "residual_floor": float(np.max(floor[r : r + k])),
        "nev": int(nev),
        "computed": len(lam),
        "n_free": n_free,
        "n_dof": int(n_dof),
        "rigid_expected": int(structure.rigid_count),
        "zero_energy_modes": int(r),
        "mechanisms": list(structure.mechanisms),
        "pieces": int(mesh.piece_count),
        "backend": backend,
        "solver": solver,
        "lumped": bool(lumped),
        "mpi_size": int(comm.size) if comm is not None else 1,
        "versions": _versions(backend, solver),
        "solver_info": dict(raw.info),
    }
    return ModalResult(
        omega=np.sqrt(lam_def), shapes=shapes, rigid_shapes=rigid_shapes, rigid_mode_count=r,
        labels=labels, certificate=cert, timings=timings, degree=int(degree), dof_points=points,
        fixed_dofs=fixed, backend=backend, solver=solver, info=info,
    )


def _diagonal_max(A, comm) -> float:
    """max |A_ii| of a scipy or (distributed) PETSc matrix."""
    if comm is None:
        d = float(np.max(np.abs(A.diagonal()))) if A.shape[0] else 0.0
    else:
        from mpi4py import MPI

        v = A.getDiagonal().getArray()
        d = comm.allreduce(float(np.max(np.abs(v))) if len(v) else 0.0, op=MPI.MAX)
    if not (np.isfinite(d) and d > 0):
        raise SolverError(f"the assembled matrix has largest diagonal entry {d!r}: check the material and the mesh")
    return d


def _scale(A, c: float) -> None:
    """A *= c in place (scipy sparse or PETSc)."""
    if hasattr(A, "data"):
        A.data *= c
    else:
        A.scale(c)


def _rigid_coupling(Z: np.ndarray, X: np.ndarray, M_ff, rows, comm) -> float:
    """max_j ||Z^T M x_j||: how far the elastic modes are from M-orthogonal to the rigid fields (0 exact)."""
    if not Z.shape[1] or not X.shape[1]:
        return 0.0
    if comm is None:
        from modalfem.eigen.spmm import spmm

        C = spmm(M_ff, Z).T @ X
    else:
        from mpi4py import MPI

        from modalfem.eigen.shift import petsc_products

        C = comm.allreduce(petsc_products(M_ff, Z, rows).T @ X[rows], op=MPI.SUM)
    return float(np.max(np.linalg.norm(C, axis=0)))
