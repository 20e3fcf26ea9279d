"""Distributed run: ``mpirun -n 2`` through the public ``modalfem.modes(..., backend="fenicsx")``.

The same small clamped P2 beam is solved in one process and on two MPI ranks (distributed assembly,
distributed SLEPc/MUMPS solve, inertia count with MUMPS ICNTL(13) = 1); the frequencies must agree
to 1e-8 relative and both certificates must pass. A second script checks ``solve_slepc`` on a
scipy pencil split over two ranks against the dense reference.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytestmark = [pytest.mark.mpi, pytest.mark.fenicsx]

HERE = os.path.dirname(os.path.abspath(__file__))

MODES_SCRIPT = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, {tests!r})
    from conftest import box_mesh
    from mpi4py import MPI
    import modalfem

    mesh = box_mesh((1.0, 0.1, 0.1), (8, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=6, degree=2, fixed="x0", backend="fenicsx", solver="slepc")
    if MPI.COMM_WORLD.rank == 0:
        c = res.certificate
        print("RESULT " + json.dumps({{"size": MPI.COMM_WORLD.size, "f": res.frequencies_hz.tolist(),
                                       "passed": bool(c.passed), "inertia": int(c.inertia_count),
                                       "below": int(c.computed_below_shift)}}))
    """
)

SOLVER_SCRIPT = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, {eigen_tests!r})
    import numpy as np, scipy.linalg as sla
    from mpi4py import MPI
    from test_slepc import random_pencil
    from modalfem.eigen.slepc import solve_slepc

    K, M = random_pencil(500, seed=3)
    raw = solve_slepc(K, M, nev=8, shift=-1.0, comm=MPI.COMM_WORLD)
    w = sla.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    m = len(raw.eigenvalues)
    G = raw.vectors.T @ (M @ raw.vectors)
    if MPI.COMM_WORLD.rank == 0:
        print("RESULT " + json.dumps({{
            "size": MPI.COMM_WORLD.size, "nprocs": raw.info["nprocs"],
            "lam_err": float(np.max(np.abs(raw.eigenvalues - w[:m]) / w[8])),
            "ortho": float(np.max(np.abs(G - np.eye(m)))),
            "inertia": int(raw.inertia_count), "dense_count": int(np.sum(w < raw.inertia_shift))}}))
    """
)


def _mpirun():
    pytest.importorskip("dolfinx")
    pytest.importorskip("slepc4py")
    exe = shutil.which("mpirun")
    if exe is None:
        pytest.skip("mpirun not found (Debian: apt-get install openmpi-bin)")
    return exe


def _run(script: str, tmp_path, nproc: int | None) -> dict:
    path = tmp_path / "script.py"
    path.write_text(script)
    env = dict(os.environ, OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1")
    if nproc is None:
        cmd = [sys.executable, str(path)]
    else:
        cmd = [_mpirun(), "--allow-run-as-root", "--oversubscribe", "-n", str(nproc), sys.executable, str(path)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path, check=False)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"{' '.join(cmd[:6])} timed out after {exc.timeout} s")
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    assert len(lines) == 1, out.stdout[-3000:] + out.stderr[-3000:]
    return json.loads(lines[0][len("RESULT "):])


def test_two_ranks_match_one_process(tmp_path):
    _mpirun()
    script = MODES_SCRIPT.format(tests=HERE)
    serial = _run(script, tmp_path, None)
    par = _run(script, tmp_path, 2)
    assert serial["size"] == 1 and par["size"] == 2
    np.testing.assert_allclose(par["f"], serial["f"], rtol=1e-8)
    assert serial["passed"] and par["passed"], (serial, par)
    # each run proves its own count: both complete
    assert par["inertia"] == par["below"] and serial["inertia"] == serial["below"]


def test_solve_slepc_split_scipy_pencil_on_two_ranks(tmp_path):
    _mpirun()
    r = _run(SOLVER_SCRIPT.format(eigen_tests=os.path.join(HERE, "eigen")), tmp_path, 2)
    assert r["size"] == 2 and r["nprocs"] == 2
    assert r["lam_err"] < 1e-9
    assert r["ortho"] < 1e-10
    assert r["inertia"] == r["dense_count"]
