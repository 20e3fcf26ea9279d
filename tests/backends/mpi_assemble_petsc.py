"""Run under ``mpirun -n P``: check ``fenicsx.assemble_petsc`` against the serial ``assemble``.

Every rank builds the same jittered, shuffled box, clamps the DOFs of nodes on x = 0 and assembles
K_ff, M_ff distributed. The locally owned rows are gathered on rank 0 into canonical free-DOF order
(rows via the returned ``rows``, columns via the gathered ``rows`` of all ranks) and compared with
the serial scipy matrices restricted to the free DOFs. Prints ``OK <max rel diff>`` on success.

Usage: ``mpirun -n 2 python mpi_assemble_petsc.py DEGREE LUMPED`` (e.g. ``2 0``).
"""

import os
import sys

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshgen import box_mesh

from modalfem.backends import fenicsx
from modalfem.material import STEEL


def gather_canonical(A, rows, comm):
    """Gather the distributed PETSc matrix A (rows in canonical free order) to scipy on rank 0."""
    indptr, cols, data = A.getValuesCSR()
    all_rows = np.concatenate(comm.allgather(rows))  # sub-matrix global index -> canonical free index
    local_r = np.repeat(rows, np.diff(indptr))
    parts = comm.gather((local_r, all_rows[cols], data), root=0)
    if comm.rank != 0:
        return None
    r, c, d = (np.concatenate(x) for x in zip(*parts))
    n = A.getSize()[0]
    return sp.csr_matrix((d, (r, c)), shape=(n, n))


def main():
    comm = MPI.COMM_WORLD
    degree, lumped = int(sys.argv[1]), bool(int(sys.argv[2]))
    mesh = box_mesh(6, 2, 3, jitter=0.3, shuffle=True, seed=3)
    dof_x = np.repeat(mesh.dof_points(degree)[:, 0], 3)
    free = dof_x > 1e-9
    K_ff, M_ff, rows = fenicsx.assemble_petsc(mesh, STEEL, degree=degree, free=free, lumped=lumped, comm=comm)
    assert K_ff.getSize() == (int(free.sum()),) * 2
    r0, r1 = K_ff.getOwnershipRange()
    assert len(rows) == r1 - r0, (len(rows), r0, r1)
    assert np.all(np.diff(rows) > 0), "rows must increase"
    counts = comm.allgather(len(rows))
    assert min(counts) > 0, f"a rank owns no rows: {counts}"
    all_rows = np.concatenate(comm.allgather(rows))
    assert np.array_equal(np.sort(all_rows), np.arange(free.sum())), "rows is not a permutation"
    Kd, Md = gather_canonical(K_ff, rows, comm), gather_canonical(M_ff, rows, comm)
    if comm.rank == 0:
        K, M = fenicsx.assemble(mesh, STEEL, degree=degree, lumped=lumped)
        idx = np.flatnonzero(free)
        Ks, Ms = K[idx][:, idx], M[idx][:, idx]
        dk = abs(Kd - Ks).max() / abs(Ks).max()
        dm = abs(Md - Ms).max() / abs(Ms).max()
        print(f"ranks={comm.size} owned={counts} dK={dk:.2e} dM={dm:.2e}")
        assert dk < 1e-12 and dm < 1e-12, (dk, dm)
        print("OK", max(dk, dm))


if __name__ == "__main__":
    main()
