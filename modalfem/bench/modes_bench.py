"""Modes benchmark: the cantilever ladder, beam theory, and one case per fresh subprocess.

A *case* (ours with FEniCSx and the default solver, ours with FEniCSx + SLEPc, ours with scikit-fem,
peer A, peer B) runs on a *rung*
(Lagrange degree and hexahedra per axis of the 1 m x 0.1 m x 0.1 m steel beam, 6 tetrahedra per
hexahedron, clamped at x = 0) in its own Python process, so its peak RSS is its own and it can be
killed at a timeout. The child is::

    python -m modalfem.bench.modes_bench --case ours-fenicsx --degree 2 --cells 40 4 4 --k 10 \
        --json-out result.json

and writes one JSON object: ``dofs``, ``setup`` (mesh + assembly) [s], ``eigen`` (everything after
assembly: constraints, factorisation, solve, certificate) [s], ``certificate`` [s] (ours only: residuals, Sylvester inertia
factorisation and checks),
``total`` [s] (mesh to eigenpairs, imports excluded), ``cpu`` [s] (CPU time of the process, all its threads,
over the same interval), ``peak_rss_mb`` (``ru_maxrss`` of the child),
``frequencies_hz`` and, for ours, ``certified``. ``run_case`` is the parent side.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

import numpy as np

__all__ = [
    "CASES",
    "CODE_PATHS",
    "K_MODES",
    "SIZE",
    "Rung",
    "code_path_here",
    "euler_bernoulli_cantilever_hz",
    "ladder",
    "run_case",
    "run_case_here",
    "timoshenko_cantilever_fe_hz",
    "timoshenko_cantilever_hz",
]

#: beam size (L, b, h) [m]
SIZE = (1.0, 0.1, 0.1)
#: steel, same numbers as ``modalfem.STEEL``: E [Pa], nu [-], rho [kg/m^3]
E, NU, RHO = 200e9, 0.3, 7850.0
#: modes per solve
K_MODES = 10

#: case name -> (short description, is ours)
CASES = {
    "ours-fenicsx": (("modalfem.modes(backend='fenicsx'), default solver (one process with MKL: block "
                      "Krylov-Schur on PARDISO, 4 right-hand sides per solve)"), True),
    "ours-slepc": ("modalfem.modes(backend='fenicsx', solver='slepc') (SLEPc Krylov-Schur on PARDISO)", True),
    "ours-skfem": ("modalfem.modes(backend='skfem'), default solver  (the pip-only path)", True),
    "peer-A": ("dolfinx + SLEPc tutorial recipe (Krylov-Schur, shift-invert 0, MUMPS LU)", False),
    "peer-B": ("scikit-fem ex03 + scipy eigsh(sigma=0), default splu", False),
}
NEEDS_FENICSX = {"ours-fenicsx", "ours-slepc", "peer-A"}
#: ours: case -> (backend, solver)
OURS = {"ours-fenicsx": ("fenicsx", "auto"), "ours-slepc": ("fenicsx", "slepc"), "ours-skfem": ("skfem", "auto")}

#: forced code paths, name -> environment of the child process. MKL picks its kernels per CPU (its AVX-512 ones
#: on Intel CPUs); OpenBLAS (MUMPS in the peer, NumPy/SciPy in both) runs Zen kernels on AMD CPUs. Forcing both
#: on an Intel machine is a PROXY for an AMD CPU (same instruction sets, not the same cores, caches or memory):
#: ``avx2`` stands for an AMD CPU on which MKL runs its AVX2 kernels, ``sse4_2`` for one on which it falls back
#: further (a pessimistic bound). ``default`` leaves both libraries to detect the CPU.
CODE_PATHS = {
    "default": {},
    "avx2": {"MKL_ENABLE_INSTRUCTIONS": "AVX2", "OPENBLAS_CORETYPE": "Zen"},
    "sse4_2": {"MKL_ENABLE_INSTRUCTIONS": "SSE4_2", "OPENBLAS_CORETYPE": "Zen"},
}


@dataclass(frozen=True)
class Rung:
    """One mesh of the ladder: Lagrange ``degree`` and hexahedra ``cells`` (nx, ny, nz)."""

    degree: int
    cells: tuple[int, int, int]

    @property
    def dofs(self) -> int:
        """All displacement DOFs (constrained included): 3 x Lagrange nodes of the box."""
        p = self.degree
        return 3 * math.prod(p * n + 1 for n in self.cells)

    @property
    def label(self) -> str:
        return "x".join(map(str, self.cells))


FULL_LADDER = [Rung(1, (20, 2, 2)), Rung(1, (40, 4, 4)), Rung(1, (80, 8, 8)), Rung(1, (160, 16, 16)),
               Rung(2, (20, 2, 2)), Rung(2, (40, 4, 4)), Rung(2, (60, 6, 6)), Rung(2, (80, 8, 8))]
QUICK_LADDER = [Rung(1, (20, 2, 2)), Rung(2, (20, 2, 2))]


def ladder(*, quick: bool = False, max_dofs: int | None = None) -> list[Rung]:
    """Rungs to run, ascending in DOFs within each degree (P1 first), capped at ``max_dofs``."""
    rungs = QUICK_LADDER if quick else FULL_LADDER
    if max_dofs is not None:
        rungs = [r for r in rungs if r.dofs <= max_dofs]
    return sorted(rungs, key=lambda r: (r.degree, r.dofs))


# ---------------------------------------------------------------------------------- beam theory
def _section(b: float, h: float):
    A = b * h
    I = min(b * h**3, h * b**3) / 12.0  # weaker axis: the lowest bending mode
    return A, I


def euler_bernoulli_cantilever_hz(*, L=SIZE[0], b=SIZE[1], h=SIZE[2], E=E, rho=RHO) -> float:
    """First bending frequency [Hz] of an Euler-Bernoulli cantilever: (beta_1 L)^2 = 1.875104^2."""
    A, I = _section(b, h)
    return 1.8751040687119611**2 / (2 * math.pi * L**2) * math.sqrt(E * I / (rho * A))


def timoshenko_cantilever_hz(*, L=SIZE[0], b=SIZE[1], h=SIZE[2], E=E, nu=NU, rho=RHO) -> float:
    """First bending frequency [Hz] of a Timoshenko cantilever, from ``modalfem.theory`` (transfer
    matrix + root finding, Cowper shear coefficient); weaker bending axis."""
    from modalfem import Material
    from modalfem.theory import rectangle_section, timoshenko_omegas

    sec = rectangle_section(b, h)
    mat = Material(E=E, nu=nu, rho=rho)
    w = min(timoshenko_omegas(mat, L, sec, direction=d, count=1)[0] for d in ("y", "z"))
    return float(w / (2 * math.pi))


def timoshenko_cantilever_fe_hz(*, L=SIZE[0], b=SIZE[1], h=SIZE[2], E=E, nu=NU, rho=RHO,
                                elements: int = 4000) -> float:
    """Independent check of ``timoshenko_cantilever_hz``: the same beam by 1D finite elements.

    Shear coefficient of a rectangle after Cowper (1966): kappa = 10 (1 + nu) / (12 + 11 nu).
    Solved by a 1D finite element model converged far below the 3D discretisation errors measured
    here: two-node elements, linear w and theta, one-point (reduced) shear integration, consistent
    mass including rotary inertia rho I; the error is O(h^2), about 1e-7 relative at 4000 elements.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import eigsh

    A, I = _section(b, h)
    G = E / (2 * (1 + nu))
    kappa = 10 * (1 + nu) / (12 + 11 * nu)
    n = elements
    le = L / n
    Bs = np.array([-1 / le, -0.5, 1 / le, -0.5])
    ke = kappa * G * A * le * np.outer(Bs, Bs)
    ke[np.ix_([1, 3], [1, 3])] += E * I / le * np.array([[1, -1], [-1, 1]])
    me = np.zeros((4, 4))
    me[np.ix_([0, 2], [0, 2])] = rho * A * le / 6 * np.array([[2, 1], [1, 2]])
    me[np.ix_([1, 3], [1, 3])] = rho * I * le / 6 * np.array([[2, 1], [1, 2]])
    dofs = 2 * np.arange(n)[:, None] + np.arange(4)[None, :]
    rows = np.repeat(dofs, 4, axis=1).ravel()
    cols = np.tile(dofs, (1, 4)).ravel()
    N = 2 * (n + 1)
    K = sp.csc_matrix((np.tile(ke.ravel(), n), (rows, cols)), shape=(N, N))
    M = sp.csc_matrix((np.tile(me.ravel(), n), (rows, cols)), shape=(N, N))
    free = np.arange(2, N)  # w and theta clamped at x = 0
    lam = eigsh(K[free][:, free], k=1, M=M[free][:, free], sigma=0, which="LM")[0]
    return float(np.sqrt(lam.min()) / (2 * math.pi))


# ---------------------------------------------------------------------------------- child side
def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _preload_modes_modules() -> None:
    """Import what ``modalfem.modes`` imports on its first call and load MKL (see ``run_case_here``)."""
    import importlib

    import scipy.sparse as sp

    for name in ("constraints", "eigen.block", "eigen.blas_threads", "eigen.certify", "eigen.labels",
                 "eigen.pardiso", "eigen.rigid", "eigen.scipy_solver", "eigen.shift", "eigen.spmm"):
        importlib.import_module(f"modalfem.{name}")
    from modalfem.eigen.pardiso import have_pardiso
    from modalfem.eigen.spmm import spmm

    if have_pardiso():
        spmm(sp.identity(1, format="csr"), np.ones((1, 1)))


def run_case_here(case: str, degree: int, cells, k: int = K_MODES) -> dict:
    """Run one case in this process and return its measurements (see module doc)."""
    cells = tuple(int(c) for c in cells)
    if case.startswith("ours-"):
        import modalfem
        from modalfem.mesh import box

        backend, solver = OURS[case]
        # Imports and library loading stay outside the clock, as in the peers (which import dolfinx, petsc4py
        # and slepc4py, loading PETSc, MUMPS and OpenBLAS, before their t0): every module modes() imports
        # lazily, and MKL (libmkl_rt and the kernels it loads on first use, by one 1 x 1 product), the
        # counterpart of the peers' PETSc libraries. The 'process' column keeps the whole cost.
        import scipy.linalg
        import scipy.ndimage
        import scipy.sparse.linalg
        import scipy.spatial  # noqa: F401
        import skfem  # noqa: F401

        _preload_modes_modules()

        if backend == "fenicsx":
            import dolfinx.fem.petsc  # noqa: F401
            import ufl  # noqa: F401
            from petsc4py import PETSc  # noqa: F401
            from slepc4py import SLEPc  # noqa: F401

            import modalfem.backends.fenicsx
            import modalfem.eigen.slepc
        else:
            import modalfem.backends.skfem
            import modalfem.eigen.scipy_solver
        t0, c0 = time.perf_counter(), time.process_time()
        mesh = box(size=SIZE, cells=cells)
        t_mesh = time.perf_counter() - t0
        material = modalfem.Material(E=E, nu=NU, rho=RHO, name="steel")
        res = modalfem.modes(mesh, material, k=k, degree=degree, fixed="x0", backend=backend, solver=solver)
        total, cpu = time.perf_counter() - t0, time.process_time() - c0
        tm = {key: float(v) for key, v in res.timings.items()}
        setup = t_mesh + tm.get("assembly", float("nan"))
        out = {
            "dofs": int(res.shapes.shape[0]),
            "setup": setup,
            "eigen": total - setup,
            # certification work: residuals + Sylvester inertia inside the solver, then the checks
            "certificate": tm.get("eigen.certificate", 0.0) + tm.get("certificate", 0.0),
            "total": total,
            "cpu": cpu,
            "timings": tm,
            "certified": bool(res.certificate.passed),
            "max_residual": float(res.certificate.max_residual),
            "frequencies_hz": [float(f) for f in res.frequencies_hz],
            "backend": res.backend,
            "solver": res.solver,
        }
    elif case in ("peer-A", "peer-B"):
        from modalfem.bench import peers

        fn = peers.peer_dolfinx_slepc if case == "peer-A" else peers.peer_skfem_scipy
        r = fn(SIZE, cells, degree, k, E, NU, RHO)
        out = {
            "dofs": r["dofs"],
            "setup": r["assembly"],
            "eigen": r["eigen"],
            "certificate": None,
            "total": r["total"],
            "cpu": r["cpu"],
            "converged": r["converged"],
            "frequencies_hz": r["frequencies_hz"],
        }
    else:
        raise ValueError(f"unknown case {case!r}; choose one of {', '.join(CASES)}")
    out["peak_rss_mb"] = _peak_rss_mb()
    out["code_path"] = code_path_here()  # after the clock: MKL is already loaded when the case used it
    return out


def _versions() -> dict:
    """Library versions and BLAS as seen by a fresh interpreter (run as ``--case info``)."""
    import platform

    import scipy

    v = {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import skfem

        v["scikit-fem"] = getattr(skfem, "__version__", "?")
    except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
        v["scikit-fem"] = "not installed"
    try:
        import dolfinx

        v["dolfinx"] = dolfinx.__version__
    except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
        v["dolfinx"] = "not installed"
    try:
        from petsc4py import PETSc

        v["PETSc"] = ".".join(map(str, PETSc.Sys.getVersion()))
    except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
        v["PETSc"] = "not installed"
    try:
        from slepc4py import SLEPc

        v["SLEPc"] = ".".join(map(str, SLEPc.Sys.getVersion()))
    except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
        v["SLEPc"] = "not installed"
    blas = "unknown"
    try:
        q = subprocess.run(["update-alternatives", "--query", "libblas.so.3-x86_64-linux-gnu"], check=False,
                           capture_output=True, text=True, timeout=10).stdout
        for line in q.splitlines():
            if line.startswith("Value:"):
                blas = line.split(":", 1)[1].strip()
    except Exception:  # noqa: BLE001, S110 - best effort (optional library, probe, sampling)
        pass
    v["BLAS (libblas.so.3)"] = blas
    v["MKL"] = _mkl_version()
    v["OpenBLAS core"] = code_path_here()["openblas"]
    # Debian 12's OpenBLAS misdetects recent Intel cores as "Prescott" (SSE3); setup pins the type
    v["OPENBLAS_CORETYPE"] = os.environ.get("OPENBLAS_CORETYPE", "autodetected")
    threads = {k: os.environ[k] for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS") if k in os.environ}
    v["BLAS threads"] = ", ".join(f"{k}={x}" for k, x in threads.items()) or "library default"
    return v


#: mkl_cbwr_get_auto_branch() codes (mkl_cbwr.h) -> the instruction set of the kernels MKL runs here
_MKL_BRANCHES = {3: "COMPATIBLE (generic)", 4: "SSE2", 6: "SSSE3", 7: "SSE4.1", 8: "SSE4.2", 9: "AVX", 10: "AVX2",
                 11: "AVX-512 MIC", 12: "AVX-512", 13: "AVX-512 MIC E1", 14: "AVX-512 E1"}


def _mkl_version() -> str:
    """MKL's version and the code path it picks on this CPU: PARDISO's numeric factorisation and solves
    run MKL's own kernels, chosen per CPU (on AMD CPUs MKL has taken slower paths than on Intel ones),
    while the orderings and the rest of the solve do not depend on it."""
    import ctypes

    from modalfem.eigen.pardiso import _library

    lib = _library()
    if lib is None:
        return "not loaded"
    try:
        buf = ctypes.create_string_buffer(512)
        lib.MKL_Get_Version_String.restype = None
        lib.MKL_Get_Version_String.argtypes = [ctypes.c_char_p, ctypes.c_int]
        lib.MKL_Get_Version_String(buf, 512)
        text = buf.value.decode(errors="replace")
        version = text.split("Version", 1)[1].split("-", 1)[0].strip() if "Version" in text else text
    except (AttributeError, IndexError, OSError):
        return "loaded (version unknown)"
    return f"{version}, code path {_mkl_branch(lib)}"


def _mkl_branch(lib) -> str:
    """The instruction set of the kernels MKL runs in this process (``mkl_cbwr_get_auto_branch``: the CPU's
    best, lowered by ``MKL_ENABLE_INSTRUCTIONS``), e.g. ``"AVX-512 E1"``, ``"AVX2"``, ``"SSE4.2"``."""
    import ctypes

    try:
        lib.mkl_cbwr_get_auto_branch.restype = ctypes.c_int
        branch = int(lib.mkl_cbwr_get_auto_branch())
    except (AttributeError, OSError):
        return "unknown"
    return _MKL_BRANCHES.get(branch, str(branch))


def code_path_here() -> dict:
    """The kernels this process runs: ``{"mkl": ..., "openblas": ...}``.

    ``mkl``: MKL's code path (see ``_mkl_branch``) if this process has loaded MKL, else ``"not loaded"`` (the
    peers never load it; it is not loaded here to ask). ``openblas``: the core type of the OpenBLAS this
    process has mapped (``openblas_get_corename``; ``OPENBLAS_CORETYPE`` overrides the detected one), or
    ``"not loaded"``.
    """
    from modalfem.bench.tet_bench import openblas_core

    pardiso = sys.modules.get("modalfem.eigen.pardiso")
    lib = getattr(pardiso, "_LIB", None)  # loaded by this process's solve, never loaded here
    return {"mkl": "not loaded" if lib is None else _mkl_branch(lib), "openblas": openblas_core() or "not loaded"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m modalfem.bench.modes_bench",
                                 description="Run one modes-benchmark case in this process.")
    ap.add_argument("--case", required=True, choices=[*CASES, "info"])
    ap.add_argument("--degree", type=int, default=2)
    ap.add_argument("--cells", type=int, nargs=3, default=(20, 2, 2))
    ap.add_argument("--k", type=int, default=K_MODES)
    ap.add_argument("--json-out", required=True)
    a = ap.parse_args(argv)
    try:
        out = _versions() if a.case == "info" else run_case_here(a.case, a.degree, a.cells, a.k)
        rc = 0
    except Exception as exc:  # noqa: BLE001 - recorded in the table, not raised
        out = {"error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]}
        rc = 1
    tmp = a.json_out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(out, f)
    os.replace(tmp, a.json_out)
    return rc


# ---------------------------------------------------------------------------------- parent side
def run_case(case: str, rung: Rung | None, *, timeout: float, k: int = K_MODES, log=None,
             env: dict | None = None) -> dict:
    """Run ``case`` on ``rung`` in a fresh ``python -m modalfem.bench.modes_bench`` process.

    The child is killed (its whole process group) after ``timeout`` seconds. Returns the child's
    measurements plus ``process`` (child wall seconds, interpreter start and imports included) and
    ``load_1min`` (the 1-minute load average when it started); ``env`` adds to or overrides the child's
    environment (e.g. one of ``CODE_PATHS``);
    on timeout ``{"timeout": timeout, "rss_seen_mb": ...}`` (RSS sampled by the parent), on failure
    ``{"error": ...}``. ``rung=None`` runs ``--case info`` (versions).
    """
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    with tempfile.TemporaryDirectory(prefix="modalfem-bench-") as tmp:
        out_path = os.path.join(tmp, "case.json")
        err_path = os.path.join(tmp, "stderr.txt")
        cmd = [sys.executable, "-m", "modalfem.bench.modes_bench", "--case", "info" if rung is None else case,
               "--k", str(k), "--json-out", out_path]
        if rung is not None:
            cmd += ["--degree", str(rung.degree), "--cells", *map(str, rung.cells)]
        env = {**os.environ, **(env or {})}
        env.setdefault("PYTHONUNBUFFERED", "1")
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
        t0 = time.perf_counter()
        with open(err_path, "w") as err:
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env, start_new_session=True)
        rss_seen = 0.0
        next_note = 30.0
        try:
            import psutil

            ps = psutil.Process(proc.pid)
        except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
            ps = None
        timed_out = False
        while proc.poll() is None:
            elapsed = time.perf_counter() - t0
            if elapsed > timeout:
                timed_out = True
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait()
                break
            if ps is not None:
                try:
                    rss_seen = max(rss_seen, ps.memory_info().rss / 2**20)
                except Exception:  # noqa: BLE001, S110 - best effort (optional library, probe, sampling)
                    pass
            if elapsed > next_note:
                log(f"    ... still running ({elapsed:.0f} s, RSS {rss_seen:.0f} MB)")
                next_note += 30.0
            time.sleep(0.1)
        wall = time.perf_counter() - t0
        if timed_out:
            return {"timeout": float(timeout), "rss_seen_mb": rss_seen, "process": wall}
        try:
            with open(out_path) as f:
                out = json.load(f)
        except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
            with open(err_path) as f:
                tail = [ln for ln in f.read().splitlines() if ln.strip()][-1:] or ["no output"]
            out = {"error": f"child exited {proc.returncode}: {tail[0][:300]}"}
        out["process"] = wall
        if load is not None and rung is not None:
            out["load_1min"] = load  # 1-minute load average when the case started
        return out


if __name__ == "__main__":
    sys.exit(main())
