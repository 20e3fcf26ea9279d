"""One world: modal, tet and cloth bodies, obstacles and effects stepped together (SI units).

API::

    from modalfem import world as mw
    from modalfem.effects import Contact, Gravity, SelfCollision, Sound

    w = mw.World(
        bodies=[mw.Modal("bell.npz", name="bell", position=(0, 0, 0.5)),
                mw.Tet(tet.tet_model(mesh, material), name="block"),
                mw.Cloth(cloth_model, name="sheet")],
        obstacles=[mw.Ground(0.0), mw.Sphere((1, 0, 0.2), 0.2, path=[(0, (0, 0, 0)), (2, (0, 1, 0))])],
        effects=[Gravity(), Contact(restitution=0.3, friction=0.5), SelfCollision(bodies=["sheet"]),
                 Sound(bodies=["bell"])],
    )
    print(w.describe_plan())               # the stages each step runs, nothing else
    state = w.state()                      # WorldState: time + one state per body
    control = w.control().add_impulse("bell", 12, (0, 0, -0.5))   # a strike [N s] at a surface vertex
    report = w.step(state, state, control, 1e-3)                  # or w.advance(state, dt, control)
    x, tris = w.surface(state, "bell")     # any body's world surface
    w.intersections(state)                 # [] : the exact triangle-triangle test between bodies
    w.sound("bell").render(2.0)            # modal sound [Pa]

Bodies: ``Modal`` (``ModalModel`` or its file), ``Tet`` (``tet.TetModel``), ``Cloth`` (``cloth.ClothModel``).
Obstacles: ``Ground``, ``Plane``, ``Sphere``, ``Box``, ``TriangleMesh``, each optionally on a ``Path``.
Effects: ``modalfem.effects`` (one vocabulary for every kind). See ``modalfem.world.world`` for the step.
"""

from modalfem.world.bodies import Cloth, ClothState, Modal, Tet
from modalfem.world.obstacles import Box, Ground, Path, Plane, Sphere, TriangleMesh
from modalfem.world.world import Stage, StepReport, World, WorldControl, WorldState

__all__ = [
    "Box",
    "Cloth",
    "ClothState",
    "Ground",
    "Modal",
    "Path",
    "Plane",
    "Sphere",
    "Stage",
    "StepReport",
    "Tet",
    "TriangleMesh",
    "World",
    "WorldControl",
    "WorldState",
]
