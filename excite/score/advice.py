"""What a weak direction means and which motion would fix it (the degenerate motions of the docs).

Each measurement kind declares the advice for its coordinates (:attr:`excite.factors.base.Kind.advice`:
the report's words and the driver's, per coordinate quantity and vehicle axis); this module looks
them up. A weak mode is an eigenvector of the scaled marginal information; its dominant
coordinates are grouped by quantity (lever arm, extrinsic rotation, time offset, bias, wheel
geometry). Lever arms and rotation axes are expressed in the vehicle frame first, so that "z"
means vertical whatever the sensor's mounting.
"""

from __future__ import annotations

import numpy as np

from ..factors import base as registry
from ..rig.config import Coordinate, Rig

REPORT, DRIVER = 0, 1  # which words: the report's, or the driver's (live guidance)
_VECTOR_QUANTITIES = ("trans", "rot", "accel_bias")  # advice per vehicle axis


def _text(c: Coordinate, axis: int | None, words: int) -> str | None:
    """The advice for coordinate ``c`` (at vehicle ``axis``): its own measurement kind's, else any kind's."""
    own = registry.kinds()
    for k in sorted(own, key=lambda k: k.name != c.source):
        hit = k.advice.get((c.quantity, axis))
        if hit is not None:
            return hit[words]
    return None


def vehicle_axis(rig: Rig, c: Coordinate) -> int | None:
    """The vehicle axis (0 forward, 1 lateral, 2 vertical) a vector coordinate points along."""
    if c.quantity not in _VECTOR_QUANTITIES:
        return None
    R_V_B = rig.config.vehicle.T_V_B.R
    e = np.zeros(3)
    e[c.axis] = 1.0
    if c.quantity == "rot":  # right perturbation: the axis is in the sensor frame
        R = next(q.nominal for _, _, q in registry.quantities(rig.config) if q.block == c.block and q.rotation)
        e = np.asarray(R) @ e
    return int(np.argmax(np.abs(R_V_B @ e)))


def _key(rig: Rig, c: Coordinate) -> tuple[str, int | None]:
    return c.quantity, vehicle_axis(rig, c)


def needs(rig: Rig, c: Coordinate) -> str:
    """What motion coordinate ``c`` still needs, in the driver's words."""
    text = _text(c, vehicle_axis(rig, c), DRIVER) or f"needs motion that determines {c.name}"
    return text[0].upper() + text[1:]


def describe(rig: Rig, coords: list[Coordinate], weights: np.ndarray, words: int = REPORT) -> str:
    """Motion advice for a mode: the advice of its one or two dominant quantities, in
    the report's words or, with ``words=DRIVER``, the driver's."""
    energy: dict[tuple[str, int | None], float] = {}
    first: dict[tuple[str, int | None], Coordinate] = {}
    for c, w in zip(coords, weights):
        key = _key(rig, c)
        energy[key] = energy.get(key, 0.0) + float(w) ** 2
        first.setdefault(key, c)
    ranked = sorted(energy.items(), key=lambda kv: -kv[1])
    parts: list[str] = []
    for k, e in ranked[:2]:
        text = _text(first[k], k[1], words)
        if (e >= 0.2 or not parts) and text is not None and text not in parts:
            parts.append(text)
    text = "; ".join(parts) or f"add motion that determines {first[ranked[0][0]].name}"
    return text[0].upper() + text[1:]
