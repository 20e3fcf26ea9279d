"""The certified modal solve on forced MKL / OpenBLAS code paths (a proxy for AMD CPUs).

MKL picks its kernels per CPU (AVX-512 on this Intel Xeon; AVX2 on AMD CPUs, which cannot run its AVX-512
ones) and OpenBLAS too (Zen kernels on AMD). Each path of ``modes_bench.CODE_PATHS`` runs one small certified
``modes()`` solve in a fresh process with the path's environment. Checked here, in this process, from the
matrices and the returned pairs (not from the child's word):

* the path took effect (MKL and OpenBLAS report the forced kernels) and the solve ran on PARDISO;
* the certificate passed, and its Sylvester count is right: an independent dense LDL^T of K - sigma M
  (SciPy, Bunch-Kaufman) counts the same eigenvalues below the certificate's shift, none below the first;
* every eigenvalue agrees with the default path's within the sum of the two results' own error bounds
  (Kahan's residual bound for the pencil, ``_eigen_bounds.residual_bounds``), and that bound is far below half
  the smallest gap between distinct eigenvalues, so a path that returned a wrong mode could not pass.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg as sla
from _eigen_bounds import residual_bounds

from modalfem.bench.modes_bench import CODE_PATHS
from modalfem.eigen.certify import PAIR_RTOL
from modalfem.eigen.pardiso import have_pardiso

pytestmark = pytest.mark.skipif(not have_pardiso(), reason="MKL PARDISO not loadable here (the paths are MKL's)")

CELLS = (10, 2, 2)  # P2: 1,575 DOFs (1,500 free; the dense counts below stay cheap)
K_MODES = 10
#: what MKL and OpenBLAS report under each forced path
#: MKL's branch and the OpenBLAS core names each forced path may report: an OpenBLAS built without a separate Zen
#: target (the scipy-openblas wheels of the pip-only venv) runs its Haswell kernels for OPENBLAS_CORETYPE=Zen and
#: names them so; Debian's reports Zen
ZEN = ("Zen", "Haswell")
EXPECTED = {"avx2": ("AVX2", ZEN), "sse4_2": ("SSE4.2", ZEN)}

CHILD = """
import json, sys
import numpy as np
import modalfem
from modalfem.bench.modes_bench import code_path_here
from modalfem.mesh import box

backend, solver, out = sys.argv[1:4]
mesh = box(size=(1.0, 0.1, 0.1), cells=({cells}))
res = modalfem.modes(mesh, modalfem.Material(E=200e9, nu=0.3, rho=7850.0), k={k}, degree=2, fixed="x0",
                     backend=backend, solver=solver)
c = res.certificate
np.savez(out, eigenvalues=res.eigenvalues, shapes=res.shapes, fixed=res.fixed_dofs)
info = res.info.get("solver_info", {{}})
with open(out + ".json", "w") as f:
    json.dump({{"passed": bool(c.passed), "inertia_shift": float(c.inertia_shift),
               "inertia_count": int(c.inertia_count), "computed_below": int(c.computed_below_shift), "code_path": code_path_here(),
               "factor": str(info.get("factor", "")) + " " + str(info.get("pardiso_ordering", ""))}}, f)
""".format(cells=", ".join(map(str, CELLS)), k=K_MODES)


def _run(path: str, backend: str, solver: str, tmp_path) -> dict:
    out = str(tmp_path / f"{path}.npz")
    env = {k: v for k, v in os.environ.items() if k not in ("MKL_ENABLE_INSTRUCTIONS", "MKL_CBWR")}
    env.update(CODE_PATHS[path])
    proc = subprocess.run([sys.executable, "-c", CHILD, backend, solver, out], env=env, capture_output=True,
                          text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    with open(out + ".json") as f:
        meta = json.load(f)
    data = np.load(out)
    return {**meta, **{k: data[k] for k in data.files}}


def _count_below(A: np.ndarray) -> int:
    """Negative eigenvalues of the symmetric A by Sylvester's law: a dense Bunch-Kaufman LDL^T (D has 1x1
    and 2x2 blocks, so it is tridiagonal)."""
    _, D, _ = sla.ldl(A)
    return int(np.sum(sla.eigvalsh_tridiagonal(np.diag(D).copy(), np.diag(D, 1).copy()) < 0))


def _check_paths(backend: str, solver: str, assemble, tmp_path):
    from modalfem.mesh import box

    results = {p: _run(p, backend, solver, tmp_path) for p in CODE_PATHS}
    default_mkl = results["default"]["code_path"]["mkl"]
    mesh = box(size=(1.0, 0.1, 0.1), cells=CELLS)
    K, M = assemble(mesh, __import__("modalfem").Material(E=200e9, nu=0.3, rho=7850.0), degree=2)
    free = ~results["default"]["fixed"]
    Kf, Mf = K[free][:, free].tocsr(), M[free][:, free].tocsr()
    Kd, Md = Kf.toarray(), Mf.toarray()
    bounds = {}
    for p, r in results.items():
        if p in EXPECTED:
            mkl, core = EXPECTED[p]
            if mkl == "AVX2" and default_mkl.startswith("SSE"):
                pytest.skip(f"this CPU has no AVX2 (MKL runs {default_mkl})")
            assert r["code_path"]["mkl"] == mkl and r["code_path"]["openblas"] in core, (p, r["code_path"])
        assert "pardiso" in r["factor"], (p, r["factor"])
        assert r["passed"], f"{p}: certificate did not pass"
        lam, X = r["eigenvalues"], r["shapes"][free]
        assert lam.shape == (K_MODES,) and np.all(np.diff(lam) >= 0)
        b = residual_bounds(Kf, Mf, X, lam)
        bounds[p] = b
        # the certificate's count, recounted here
        sigma = r["inertia_shift"]
        assert lam[-1] + b[-1] < sigma
        assert _count_below(Kd - sigma * Md) == r["inertia_count"] == r["computed_below"] >= K_MODES
    # and nothing below the first eigenvalue of any path
    assert _count_below(Kd - min(r["eigenvalues"][0] - bounds[p][0] for p, r in results.items()) * Md) == 0
    ref = results["default"]["eigenvalues"]
    # a wrong mode cannot hide inside the bounds: distinct eigenvalues (gap above the degenerate-pair
    # tolerance) are further apart than twice the largest bound
    gaps = np.diff(ref)
    distinct = gaps[gaps > PAIR_RTOL * ref[1:]]
    worst = max(float(np.max(b)) for b in bounds.values())
    assert distinct.size and 2 * worst < 0.5 * distinct.min(), (worst, distinct.min())
    for p, r in results.items():
        diff = np.abs(r["eigenvalues"] - ref)
        assert np.all(diff <= bounds[p] + bounds["default"]), (p, diff, bounds[p] + bounds["default"])
    return results


def test_block_solver_on_every_code_path_agrees_within_certified_bounds(tmp_path):
    """modes(backend='skfem'): the default block Krylov-Schur on PARDISO (the pip-only path)."""
    from modalfem.backends.skfem import assemble

    _check_paths("skfem", "auto", assemble, tmp_path)


@pytest.mark.fenicsx
def test_slepc_solver_on_every_code_path_agrees_within_certified_bounds(tmp_path):
    """modes(backend='fenicsx', solver='slepc'): SLEPc's Krylov-Schur on PARDISO."""
    pytest.importorskip("dolfinx")
    from modalfem.backends.fenicsx import assemble

    _check_paths("fenicsx", "slepc", assemble, tmp_path)
