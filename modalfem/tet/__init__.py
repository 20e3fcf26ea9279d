"""Large-deformation tetrahedral bodies: corotational / invertible FEM, volume springs, implicit steps.

API::

    from modalfem import tet

    model = tet.tet_model(mesh, material, energy="stable")       # fixed data (or energy="corotated")
    solver = tet.TetSolver(model, effects=[tet.Gravity(), tet.Ground(0.0, stiffness=1e5),
                                           tet.RayleighDamping(alpha=1.0), tet.Pins(ids)])
    state = tet.TetState.at_rest(model)
    info = solver.step(state, state, dt, control=tet.TetControl(ids2, positions))  # scripted vertices
    solver.energies(state)                                       # kinetic, elastic, ... [J]

Only the effects passed to the solver are evaluated. Pieces: ``kinematics`` (F, dF/dx, rotation-variant
SVD, polar), ``energies`` (isotropic densities with analytic, projectable Hessians), ``model``,
``assembly`` (fixed CSR pattern), ``effects``, ``solver`` (backward Euler / BDF2, Newton, PCG or
SuperLU), ``precond`` (two-level preconditioner), ``modal_compare`` (linear modal references: the
real-time ``modalfem.runtime`` driven by an impulse, and an exact superposition with rigid modes),
``frames`` (PNG frame sheets).
"""

from modalfem.effects import (
    Gravity,  # the one vocabulary (modalfem.effects); TetSolver maps it
)
from modalfem.tet.effects import (
    Ground,
    Pins,
    RayleighDamping,
    VolumeBarrier,
    VolumeSprings,
)
from modalfem.tet.frames import plot_frame_sheet
from modalfem.tet.model import ENERGIES, TetModel, tet_model
from modalfem.tet.solver import (
    LINEAR_SOLVERS,
    StepInfo,
    TetControl,
    TetSolver,
    TetState,
)

__all__ = [
    "ENERGIES",
    "LINEAR_SOLVERS",
    "Gravity",
    "Ground",
    "Pins",
    "RayleighDamping",
    "StepInfo",
    "TetControl",
    "TetModel",
    "TetSolver",
    "TetState",
    "VolumeBarrier",
    "VolumeSprings",
    "plot_frame_sheet",
    "tet_model",
]
