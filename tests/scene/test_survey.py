"""The survey of a scene (``excite scene info``): where a lidar is degenerate and along what,
against the scenes whose null directions are known exactly (the design's degenerate scenes)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from excite.core import so3
from excite.scene import shapes, survey
from excite.scene.model import Scene


def readings(s: survey.Survey) -> list[survey.Reading]:
    return [r for row in s.readings for r in row]


def test_an_open_lot_leaves_x_y_and_yaw_everywhere():
    s = survey.survey(shapes.ground(-60, -40, 60, 40), spacing_m=20.0)
    assert (s.x_m.size, s.y_m.size) == (6, 4)
    assert all(r.status == "degenerate" and set(r.unobservable) == {"x translation", "y translation", "yaw"}
               for r in readings(s))
    assert s.rows() == ["AAAAAA"] * 4
    assert s.legend() == [("A", "no information along yaw, x translation, y translation", 24)]


def test_a_tunnel_leaves_its_axis_and_a_wall_the_translation_along_it():
    tunnel = shapes.tunnel(400.0, 12.0, 6.0, x0=-200.0)
    s = survey.survey(tunnel, spacing_m=50.0)
    assert s.y_m.size == 1 and all(r.unobservable == ("x translation",) for r in readings(s))
    # a wall at 30° from x on level ground: the translation along it, named by its bearing
    R = so3.rot_z(math.radians(30.0))[:2, :2]
    wall = Scene.combine([shapes.ground(-120, -120, 120, 120), shapes.wall(R @ [-70, 10], R @ [70, 10], 5.0)])
    s = survey.survey(wall, spacing_m=40.0)
    seen = [r for r in readings(s) if r.status != "inside"]
    assert seen and all(r.unobservable == ("translation along 30°",) for r in seen)


def test_a_point_inside_a_building_or_on_its_wall_is_not_scanned():
    scene = Scene.combine([shapes.ground(-50, -50, 50, 50), shapes.box(-10, -10, 10, 10, 8.0)])
    s = survey.survey(scene, spacing_m=10.0)  # points at ±5, ±15, …: two by two inside the box
    inside = [(x, y) for j, y in enumerate(s.y_m) for i, x in enumerate(s.x_m) if s.readings[j][i].status == "inside"]
    assert sorted(inside) == [(-5.0, -5.0), (-5.0, 5.0), (5.0, -5.0), (5.0, 5.0)]
    scene = Scene.combine([shapes.ground(-40, -40, 40, 40), shapes.box(-10, -20, 10, 20, 8.0)])
    s = survey.survey(scene, spacing_m=20.0)  # points at ±10, ±30: four on the box's walls
    on = [(x, y) for j, y in enumerate(s.y_m) for i, x in enumerate(s.x_m) if s.readings[j][i].status == "inside"]
    assert sorted(on) == [(-10.0, -10.0), (-10.0, 10.0), (10.0, -10.0), (10.0, 10.0)]
    # the ground under a building is found through its roof
    z = survey.ground_heights(scene, np.array([[0.0, 0.0], [30.0, 30.0]]))
    assert z == pytest.approx([0.0, 0.0], abs=1e-6)  # the ray caster works in float32


def test_weak_is_a_scan_sigma_above_the_reference():
    """One scan's information, diagonal: σ 1 cm in x translation is clear, 3 cm is weak, none is
    no information (the reference σ: 2 cm, 0.05°)."""
    def H(sx):
        d = np.array([1e-5] * 3 + [sx, 1e-3, 1e-3])
        return np.diag(np.where(np.isinf(d), 0.0, 1.0 / d**2))

    assert survey.read_scan(H(0.01), 100).status == "clear"
    weak = survey.read_scan(H(0.03), 100)
    assert (weak.status, weak.weak, weak.unobservable) == ("weak", ("x translation",), ())
    assert weak.weakest_sigma_in_reference == pytest.approx(0.03 / survey.REFERENCE_SIGMA_M)
    null = survey.read_scan(H(np.inf), 100)
    assert (null.status, null.unobservable) == ("degenerate", ("x translation",))
    assert survey.read_scan(np.zeros((6, 6)), 0).status == "blind"


def test_directions_are_named_by_the_axes_they_span_whatever_the_basis():
    rng = np.random.default_rng(3)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    W = np.zeros((6, 3))
    W[[2, 3, 4], :] = Q  # a random basis of yaw, x and y translation
    assert survey.name_directions(W) == ["yaw", "x translation", "y translation"]
    v = np.zeros((6, 1))
    v[3], v[4] = math.cos(math.radians(-60.0)), math.sin(math.radians(-60.0))
    assert survey.name_directions(v) == ["translation along 120°"]  # a direction, not a sense
    v = np.zeros((6, 1))
    v[2], v[3] = 0.6, 0.8
    assert survey.name_directions(v) == ["x translation + yaw"]


def test_the_grid_is_bounded():
    big = shapes.ground(0, 0, 20_000, 3_000)
    s, x, y = survey.grid(big, 5.0)
    assert x.size <= survey.MAX_COLUMNS and x.size * y.size <= survey.MAX_CELLS
    assert s > 5.0 and x[-1] - x[0] <= 20_000 and (x[-1] - x[0]) + s >= 20_000 - 1e-6
    assert survey.grid(shapes.ground(0, 0, 100, 50), 5.0)[1].size == 20
