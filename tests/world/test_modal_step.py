"""The World's modal bodies stepped in one compiled call (``world._modal_step``): the same states as each body's
``ModalSolver.step``, and the solvers not called for the bodies it steps."""

from __future__ import annotations

import numpy as np

from modalfem import world as mw
from modalfem.effects import Contact, Damping, Gravity
from modalfem.runtime.rotation import quat_from_axis_angle
from modalfem.world import world as world_module

_FIELDS = ("position", "velocity", "angular_momentum", "orientation", "q", "qdot")


def test_the_batched_modal_step_gives_each_solvers_states(bar_model, monkeypatch):
    """Four bars with gravity and modal damping tumbling onto the ground and each other (the solve's impulses taken
    at the step start), one struck every 7th step (that one goes through its solver): from the same state, one
    world step with the batch and one with every body through its solver agree in every field to rounding (the
    same operations; a 3 x 3 product's order of sums and sin and cos may differ in the last bit), at each of 120 steps.
    The reference steps in a second World of the same bodies: its solvers' scratch states are not the batch's (on
    one World the reference's step wrote the scratch states that the batched step then handed over)."""
    rng = np.random.default_rng(2)
    bodies = []
    for i in range(4):
        axis = rng.normal(size=3)
        bodies.append(mw.Modal(bar_model, name=f"b{i}", position=(0.03 * i, 0.01 * i, 0.04 + 0.06 * i),
                               orientation=quat_from_axis_angle(axis / np.linalg.norm(axis), rng.uniform(0, 3)),
                               velocity=0.3 * rng.normal(size=3), angular_velocity=3.0 * rng.normal(size=3)))

    def world():
        return mw.World(bodies=bodies, obstacles=[mw.Ground(0.0)],
                        effects=[Gravity(), Damping(alpha=2.0, beta=1e-7), Contact(restitution=0.3, friction=0.4)])

    w, w_ref = world(), world()
    s = w.state()
    for b in bodies:
        s[b.name].q[:] = 1e-6 * rng.normal(size=len(s[b.name].q))
    calls = {b.name: 0 for b in bodies}
    for b in bodies:
        solver = w._modal[b.name]["solver"]
        step = solver.step

        def counted(*a, _step=step, _name=b.name, **k):
            calls[_name] += 1
            return _step(*a, **k)

        monkeypatch.setattr(solver, "step", counted)
    touched = 0
    for k in range(120):
        ctl = w.control()
        if k % 7 == 3:
            ctl.add_impulse("b1", 5, [0.0, 0.5, 1.0])  # at surface vertex 5
        start = s.copy()
        ref = s.copy()  # both steps from copies (a copy's orientation is renormalised: not bit for bit ``s``)
        s = s.copy()
        monkeypatch.setattr(world_module, "MODAL_BATCH", False)
        w_ref.step(ref, ref, ctl, 1e-3)
        monkeypatch.setattr(world_module, "MODAL_BATCH", True)
        before = dict(calls)
        r = w.step(s, s, ctl, 1e-3)
        touched += r.contacts.get("solid", 0) > 0
        assert calls["b0"] == before["b0"] and calls["b2"] == before["b2"]  # batched: no solver call
        assert calls["b1"] == before["b1"] + (k % 7 == 3)  # struck: through its solver
        for b in bodies:
            for f in _FIELDS:
                got, want = getattr(s[b.name], f), getattr(ref[b.name], f)
                # rounding of ~10 operations on the larger of the start and end values (a kick may cancel)
                scale = max(float(np.abs(want).max()), float(np.abs(getattr(start[b.name], f)).max()), 1e-300)
                assert np.allclose(got, want, rtol=0, atol=1e-13 * scale), (k, b.name, f, got - want, scale)
            assert s[b.name].time == ref[b.name].time
    assert touched > 20
