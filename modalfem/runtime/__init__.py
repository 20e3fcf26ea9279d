"""Real-time modal runtime (numpy, numba): exact per-mode integration, rigid body, impulses, contact.

Importing ``modalfem.runtime`` loads numpy, numba (the compiled contact kernels) and the standard library
only (no scipy, scikit-fem, dolfinx or petsc4py; a test checks it). SI units throughout.

API (stable)::

    from modalfem import runtime as rt

    body = rt.load("bell.npz")                    # ModalModel file -> ModalBody (or rt.ModalBody(model))
    solver = rt.ModalSolver(body, effects=[       # effects are opt-in; none -> bare modal + rigid update
        rt.Gravity(),                             #   m g at the centre of mass
        # rt.Wind((5.0, 0, 0)),                   #   pressure on windward triangles [m/s]
        rt.Obstacles([rt.Ground(0.0), rt.Sphere((0, 0, 1), 0.2)], restitution=0.3, friction=0.5),
        # rt.PseudoForces(),                      #   Coriolis / centripetal / Euler on the modes (coupling stored in the model)
    ])
    state = solver.state(position=(0, 0, 1.0), angular_velocity=(0, 0, 2.0))   # State at rest / moving
    control = rt.Control().add_impulse(body.surface_point(12, (0.2, 0.3, 0.5)), (0, 0, -0.5))  # [N s]
    hit = body.locate(state, picked_xyz)          # world point -> SurfacePoint (error if off the surface)
    contacts = solver.collide(state, dt)          # None without obstacle effects
    solver.step(state, state_next, control, contacts, dt)   # or solver.advance(state, dt, control)
    x = body.positions(state_next)                # (nv, 3) world surface vertices  c + R (X + Phi q)
    nrm = body.normals(x)                         # (nv, 3) unit vertex normals (area-weighted)

State (``rt.State``): ``q``, ``qdot`` (r,) [sqrt(kg) m, sqrt(kg) m/s]; ``position`` (centre of mass,
3) [m]; ``orientation`` quaternion (w, x, y, z) body -> world; ``velocity`` (3) [m/s];
``angular_momentum`` (3) [kg m^2/s] world; ``time`` [s]. ``body.angular_velocity(state)`` [rad/s].

Surface points are ``SurfacePoint(triangle, barycentric)`` or a vertex index. Pseudo-forces need
the rotation coupling of the modes, which ``ModalModel.from_modes`` computes and stores in the model
file (``rotation_T``, ``rotation_S``); ``rt.PseudoForces()`` uses it. For an older file, pass
``rt.RotationCoupling.from_matrices(result.shapes, M, result.dof_points, model.center_of_mass)``.
Mode shapes are stored modes-major, ``body.shapes_t`` (r, 3 nv) (``body.shapes`` is its transpose).

For sound: modal state ``state.q``/``state.qdot`` with ``body.omega`` [rad/s] and ``body.mu`` [1/s];
``contacts.impulses`` (k,) [N s] after a step holds the normal impulses of the contact solve.

Pieces: ``integrator`` (exact oscillator steps, ``transition``), ``rotation`` (quaternions, free
rigid rotation), ``body`` (``ModalBody``, ``SurfacePoint``, ``load``), ``state`` (``State``,
``Control``), ``solver`` (``ModalSolver``, ``Loads``), ``effects`` (the runtime's implementations of
``Gravity`` and ``Wind``, which are ``modalfem.effects``' classes; ``PseudoForces``, ``RotationCoupling``),
``obstacles`` (``Plane``, ``Ground``, ``Sphere``, ``Box``, ``Obstacles``), ``contact``
(``Contacts``; compiled kernels in ``_contact_kernels``), ``pairs`` (contact between modal bodies).
Errors: ``SimulationError`` (dt <= 0, NaN impulse, point off the surface),
``ModelFileError`` (bad or newer model file), ``InputError`` (bad effect parameters).
"""

from modalfem.effects import (  # the one vocabulary (modalfem.effects); the solver maps them
    Gravity,
    Wind,
)
from modalfem.runtime.body import ModalBody, SurfacePoint, load
from modalfem.runtime.contact import Contacts
from modalfem.runtime.effects import PseudoForces, RotationCoupling
from modalfem.runtime.integrator import ModalIntegrator, transition
from modalfem.runtime.obstacles import Box, Ground, Obstacles, Plane, Sphere
from modalfem.runtime.solver import Loads, ModalSolver
from modalfem.runtime.sound import ModalSound
from modalfem.runtime.state import Control, State
from modalfem.runtime.wav import read_wav, write_wav

__all__ = [
    "Box",
    "Contacts",
    "Control",
    "Gravity",
    "Ground",
    "Loads",
    "ModalBody",
    "ModalIntegrator",
    "ModalSolver",
    "ModalSound",
    "Obstacles",
    "Plane",
    "PseudoForces",
    "RotationCoupling",
    "Sphere",
    "State",
    "SurfacePoint",
    "Wind",
    "load",
    "read_wav",
    "transition",
    "write_wav",
]
