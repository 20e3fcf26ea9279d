"""The solid stage's layout of the solve's bodies is made once per world (``_SolidStage._solid_layout``): with it,
each body's obstacles handled by the Python contact builder are its moving and mesh obstacles, never a static plane
of the compiled modal contacts (those are the compiled search's: counted twice, a resting body's ground contacts
would be doubled in the solve)."""

from __future__ import annotations

from modalfem import world as mw
from modalfem.effects import Contact, Gravity


def _world(bar_model, with_box: bool):
    contact = Contact(restitution=0.0, friction=0.3)
    w0 = mw.World(bodies=[mw.Modal(bar_model, name="b")], effects=[])
    s0 = w0.state()
    zmin = w0.surface(s0, "b")[0][:, 2].min() - s0.bodies["b"].position[2]
    obstacles = [mw.Ground()]
    if with_box:  # a moving box far from both bars: no contact of its own
        obstacles.append(mw.Box((5.0, 5.0, 5.0), (0.05, 0.1, 0.1), path=lambda t: (0.1 * t, 0.0, 0.0)))
    return mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0.0, 0.0, 0.5 * contact.margin - zmin)),
                            mw.Modal(bar_model, name="other", position=(0.0, 1.0, 0.5 * contact.margin - zmin))],
                    obstacles=obstacles, effects=[Gravity(), contact])


def test_static_planes_are_not_handled_twice(bar_model):
    counts = {}
    for with_box in (False, True):
        w = _world(bar_model, with_box)
        s = w.state()
        # the ground's contacts at the start: each bar's surface vertices within the margin of it (the bottom face's
        # at the skin, half the margin; the others a bar's thickness higher)
        near = sum(int((w.surface(s, n)[0][:, 2] < w._one(n, Contact).margin).sum()) for n in ("bar", "other"))
        counts[with_box] = [w.step(s, s, None, 1e-3).contacts["solid"] for _ in range(5)]
        assert counts[with_box][0] == near, "the ground's contacts counted again"
        layout = w._solid_layout()
        assert w._solid_layout() is layout  # made once
        box_tags = [i for i, o in enumerate(w.obstacles) if isinstance(o, mw.Box)]
        assert [(n, [t for _, t in obs]) for n, obs in layout["obstacles"]] == [(n, box_tags) for n in ("bar", "other")]
    assert counts[False][0] > 0 and counts[True] == counts[False]
