"""A scene seen from above: each surface's outline as segments, bounded."""

from __future__ import annotations

import numpy as np

from excite.scene import shapes
from excite.scene.model import Scene
from excite.scene.outline import outlines


def _edges(segments) -> set[tuple]:
    return {tuple(sorted([(round(a, 3), round(b, 3)), (round(c, 3), round(d, 3))])) for a, b, c, d in segments}


def test_footprints_walls_and_poles_from_above():
    L = [(0, 0), (20, 0), (20, 10), (10, 10), (10, 25), (0, 25)]  # an L-shaped building: a concave roof
    scene = Scene.combine([shapes.ground(-50, -50, 50, 50), shapes.prism(L, 12.0, name="L"),
                           shapes.wall((-40, -30), (30, -30), 3.0, name="fence"),
                           shapes.cylinder((-20, 20), 0.3, 6.0, sides=8, name="lamp")])
    out = {s["name"]: s for s in outlines(scene)["surfaces"]}
    ring = L + [L[0]]
    assert _edges(out["L"]["segments"]) == _edges([(*a, *b) for a, b in zip(ring, ring[1:])])
    assert _edges(out["fence"]["segments"]) == {((-40, -30), (30, -30))}
    assert len(out["lamp"]["segments"]) == 8  # the pole's top, its sides seen as the same edges
    assert _edges(out["ground"]["segments"]) == _edges([(-50, -50, 50, -50), (50, -50, 50, 50),
                                                        (50, 50, -50, 50), (-50, 50, -50, -50)])
    assert not any(s["boxed"] for s in out.values())


def test_beyond_the_bound_a_surface_is_its_rectangle_and_then_left_out():
    rng = np.random.default_rng(1)
    poles = [shapes.cylinder(tuple(rng.uniform(-40, 40, 2)), 0.2, 3.0, sides=12, name=f"pole {i}") for i in range(6)]
    scene = Scene.combine([shapes.ground(-50, -50, 50, 50), *poles])
    out = outlines(scene, max_segments=30)
    n = sum(len(s["segments"]) for s in out["surfaces"])
    assert n <= 30 and out["boxed"] >= 1 and out["omitted"] >= 1
    assert out["boxed"] + out["omitted"] + sum(not s["boxed"] for s in out["surfaces"]) == len(scene.surfaces)
    for s in out["surfaces"]:
        if s["boxed"]:
            assert len(s["segments"]) == 4
