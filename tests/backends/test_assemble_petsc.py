"""Distributed FEniCSx assembly restricted to free DOFs (``fenicsx.assemble_petsc``)."""

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from meshgen import box_mesh

from modalfem.errors import InputError
from modalfem.material import STEEL

pytestmark = pytest.mark.fenicsx
HERE = os.path.dirname(os.path.abspath(__file__))


def petsc_to_scipy(A):
    import scipy.sparse as sp

    indptr, indices, data = A.getValuesCSR()
    return sp.csr_matrix((data, indices, indptr), shape=A.getSize())


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("lumped", [False, True])
def test_serial_matches_assemble(degree, lumped):
    pytest.importorskip("dolfinx")
    from modalfem.backends import fenicsx

    mesh = box_mesh(3, 2, 2, jitter=0.3, shuffle=True, seed=8)
    free = np.repeat(mesh.dof_points(degree)[:, 2], 3) > 1e-9  # clamp z = 0
    free[::7] = False  # and some scattered single components
    K_ff, M_ff, rows = fenicsx.assemble_petsc(mesh, STEEL, degree=degree, free=free, lumped=lumped)
    n_free = int(free.sum())
    assert np.array_equal(rows, np.arange(n_free))
    K, M = fenicsx.assemble(mesh, STEEL, degree=degree, lumped=lumped)
    idx = np.flatnonzero(free)
    Kp, Mp = petsc_to_scipy(K_ff), petsc_to_scipy(M_ff)
    assert abs(Kp - K[idx][:, idx]).max() <= 1e-12 * abs(K).max()
    assert abs(Mp - M[idx][:, idx]).max() <= 1e-12 * abs(M).max()
    if lumped:
        assert Mp.nnz == n_free


def test_all_free_by_default_and_bad_mask():
    pytest.importorskip("dolfinx")
    from modalfem.backends import fenicsx

    mesh = box_mesh(2, 1, 1)
    K_ff, _, rows = fenicsx.assemble_petsc(mesh, STEEL, degree=1)
    assert K_ff.getSize() == (3 * mesh.point_count,) * 2 and len(rows) == 3 * mesh.point_count
    with pytest.raises(InputError, match="bool mask"):
        fenicsx.assemble_petsc(mesh, STEEL, degree=2, free=np.ones(3 * mesh.point_count, bool))
    with pytest.raises(InputError, match="bool mask"):
        fenicsx.assemble_petsc(mesh, STEEL, degree=1, free=np.ones(3 * mesh.point_count, int))


@pytest.mark.mpi
@pytest.mark.parametrize("degree, lumped", [(2, 0), (1, 1), (2, 1)])
def test_two_ranks_match_serial(degree, lumped):
    pytest.importorskip("dolfinx")
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        pytest.skip("mpirun not found")
    cmd = [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable,
           os.path.join(HERE, "mpi_assemble_petsc.py"), str(degree), str(lumped)]
    env = dict(os.environ, OMPI_MCA_rmaps_base_oversubscribe="1")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, check=False)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "OK" in out.stdout and "ranks=2" in out.stdout, out.stdout
