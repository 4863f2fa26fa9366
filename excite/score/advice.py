"""What a weak direction means and which motion would fix it (DESIGN.md's degenerate motions).

A weak mode is an eigenvector of the scaled marginal information; its dominant coordinates are
grouped by kind (lever arm, extrinsic rotation, time offset, bias, wheel geometry). Lever arms and
rotation axes are expressed in the vehicle frame first, so that "z" means vertical whatever the
sensor's mounting.
"""

from __future__ import annotations

import numpy as np

from ..rig.config import Coordinate, Rig

_AXIS_WORD = {0: "forward", 1: "lateral", 2: "vertical"}

_ADVICE = {
    ("trans", 2): "vertical lever arm: add pitch and roll (hard braking and acceleration, ramps, "
                  "brisk cornering); planar driving leaves it nearly undetermined",
    ("trans", 0): "horizontal lever arm: add yaw at changing speed (turns both ways, figure-eight, "
                  "slalom)",
    ("trans", 1): "horizontal lever arm: add yaw at changing speed (turns both ways, figure-eight, "
                  "slalom)",
    ("rot", 0): "extrinsic rotation about the travel direction: add turns; straight driving "
                "leaves it undetermined",
    ("rot", 1): "extrinsic rotation about the lateral axis: add turns and pitch (braking, ramps)",
    ("rot", 2): "extrinsic rotation about the vertical axis: add straight runs and turns",
    ("time_offset", None): "time offset: vary angular rate and acceleration (slalom, stop-and-go); "
                           "constant velocity hides it",
    ("gyro_bias", None): "gyroscope bias: add rotation the exteroceptive sensors see too, or drive longer",
    ("accel_bias", 0): "horizontal accelerometer bias: add heading changes (turns) to separate it "
                       "from roll and pitch",
    ("accel_bias", 1): "horizontal accelerometer bias: add heading changes (turns) to separate it "
                       "from roll and pitch",
    ("accel_bias", 2): "vertical accelerometer bias: vary acceleration and attitude",
    ("radius", None): "wheel radii: drive several curvatures, left, right and straight; one "
                      "constant curvature leaves a radii/track combination undetermined",
    ("track", None): "wheel track: turn both ways; straight driving says nothing about it",
    ("scale", None): "monocular scale: accelerate and decelerate",
}


# The same, in the words of whoever drives: what motion a direction still needs.
NEEDS = {
    ("trans", 2): "needs pitch and roll: a ramp, hard braking, brisk cornering",
    ("trans", 0): "needs turns both ways at changing speed: a figure-eight, a slalom",
    ("trans", 1): "needs turns both ways at changing speed: a figure-eight, a slalom",
    ("rot", 0): "needs turns: straight driving cannot reach it",
    ("rot", 1): "needs turns and pitch: braking, a ramp",
    ("rot", 2): "needs straight runs and turns",
    ("time_offset", None): "needs changing turn rate and speed: a slalom, stop-and-go",
    ("gyro_bias", None): "needs rotation, or a longer drive",
    ("accel_bias", 0): "needs heading changes: turn left and right",
    ("accel_bias", 1): "needs heading changes: turn left and right",
    ("accel_bias", 2): "needs changing speed and attitude: braking, a ramp",
    ("radius", None): "needs several curvatures: turn left, turn right, drive straight",
    ("track", None): "needs turns: turn both ways",
    ("scale", None): "needs speed changes: accelerate and brake",
}


def vehicle_axis(rig: Rig, c: Coordinate) -> int | None:
    """The vehicle axis (0 forward, 1 lateral, 2 vertical) a vector coordinate points along."""
    if c.kind not in ("trans", "rot", "accel_bias"):
        return None
    R_V_B = rig.config.vehicle.T_V_B.R
    e = np.zeros(3)
    e[c.axis] = 1.0
    if c.kind == "rot":  # right perturbation: the axis is in the sensor frame
        sensor = next(s for s in rig.config.sensors if s.name == c.block)
        e = sensor.T_B_S.R @ e
    return int(np.argmax(np.abs(R_V_B @ e)))


def needs(rig: Rig, c: Coordinate) -> str:
    """What motion coordinate ``c`` still needs, in the driver's words (:data:`NEEDS`)."""
    text = NEEDS[(c.kind, vehicle_axis(rig, c) if (c.kind, 0) in NEEDS else None)]
    return text[0].upper() + text[1:]


def describe(rig: Rig, coords: list[Coordinate], weights: np.ndarray,
             table: dict[tuple[str, int | None], str] = _ADVICE) -> str:
    """Motion advice for a mode: the advice of its one or two dominant kinds of coordinate, from
    ``table`` (the report's :data:`_ADVICE`, or :data:`NEEDS` for the driver)."""
    energy: dict[tuple[str, int | None], float] = {}
    for c, w in zip(coords, weights):
        key = (c.kind, vehicle_axis(rig, c) if (c.kind, 0) in table else None)
        energy[key] = energy.get(key, 0.0) + float(w) ** 2
    ranked = sorted(energy.items(), key=lambda kv: -kv[1])
    parts: list[str] = []
    for k, e in ranked[:2]:
        if (e >= 0.2 or not parts) and k in table and table[k] not in parts:
            parts.append(table[k])
    text = "; ".join(parts)
    return text[0].upper() + text[1:]
