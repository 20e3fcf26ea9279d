"""The scikit-fem backend works without FEniCSx (no dolfinx/petsc4py/ufl/mpi4py import anywhere)."""

import subprocess
import sys

SCRIPT = r"""
import sys
for name in ("dolfinx", "petsc4py", "slepc4py", "ufl", "mpi4py", "basix", "ffcx"):
    sys.modules[name] = None  # any import of these now raises ImportError
sys.path.insert(0, sys.argv[1])
from meshgen import box_mesh
from modalfem.backends import get_backend, resolve_backend
from modalfem.material import STEEL
assert resolve_backend("auto") == "skfem"
K, M = get_backend("skfem").assemble(box_mesh(2, 1, 1), STEEL, degree=2)
assert K.shape == M.shape == (3 * 45, 3 * 45), K.shape
import modalfem.forms.skfem_elasticity
print("OK")
"""


def test_skfem_backend_without_fenicsx():
    import os

    here = os.path.dirname(os.path.abspath(__file__))
    out = subprocess.run([sys.executable, "-c", SCRIPT, here], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("OK")
