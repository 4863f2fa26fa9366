"""Terrain features of a lot: ramps, banked sections, speed bumps.

Each feature is a convex polygon (local metres) over which the road surface is tilted. The lot's
terrain is its *slope field* ``s(x, y) = ∇h`` (rise per metre along x and y): the sum over the
features of a smooth indicator of the polygon (a product of ``½(1 + tanh(d/ε))`` over its edges,
``d`` the signed distance to the edge's line, ``ε`` = 0.4 m) times the feature's slope:

- ``ramp`` and ``bank``: a tilted plane, ``slope_deg`` rising towards ``uphill_deg``
  (counter-clockwise from local x / east); a ramp is driven up and down its slope, a bank
  across it — the model is the same;
- ``bump``: a ``height_m`` high cosine bump across the polygon along ``across_deg``; the
  vehicle crosses it at most at ``max_speed_mps`` (default 2.5 m/s).

A vehicle at (x, y) heading ψ sees the grade ``atan(s·(cos ψ, sin ψ))`` (positive uphill) and the
bank ``atan(s·(−sin ψ, cos ψ))`` (positive: left side up), exactly the ``grade_rad`` and
``bank_rad`` of :class:`~excite.motion.vehicle.ControlProfile`. The slope is written once in CasADi
(:meth:`Terrain.slope`), so the optimizer differentiates the same function the check evaluates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ..errors import OptimizeError

EDGE_SOFTNESS_M = 0.4
BUMP_SPEED_MPS = 2.5


@dataclass(frozen=True)
class Feature:
    """One terrain feature: ``role``, its convex ``polygon_m`` (n, 2, counter-clockwise) and
    its parameters (``slope`` rise per metre and unit ``direction`` for ramps and banks;
    ``height_m``, ``direction`` and ``max_speed_mps`` for bumps)."""

    role: str
    polygon_m: np.ndarray
    direction: tuple[float, float]
    slope: float = 0.0
    height_m: float = 0.0
    max_speed_mps: float | None = None

    def extent_along(self) -> tuple[float, float]:
        s = self.polygon_m @ np.asarray(self.direction)
        return float(s.min()), float(s.max())

    def contains(self, p: np.ndarray) -> np.ndarray:
        """Points (n, 2) inside the polygon (convex, counter-clockwise)."""
        a = self.polygon_m
        e = np.roll(a, -1, axis=0) - a
        cross = e[None, :, 0] * (p[:, None, 1] - a[None, :, 1]) - e[None, :, 1] * (p[:, None, 0] - a[None, :, 0])
        return np.all(cross >= 0, axis=1)


MAX_FEATURE_VERTICES = 16  # a convex ramp, bank or bump: each edge is a factor of its smooth indicator


def _convex_ccw(ring: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(ring, dtype=float)
    if len(a) > MAX_FEATURE_VERTICES:
        raise OptimizeError(f"{what}: {len(a)} vertices, over the limit of {MAX_FEATURE_VERTICES} for a "
                            "terrain feature (a convex polygon)")
    area2 = np.sum(a[:, 0] * np.roll(a[:, 1], -1) - np.roll(a[:, 0], -1) * a[:, 1])
    if area2 < 0:
        a = a[::-1]
    e = np.roll(a, -1, axis=0) - a
    cr = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    if abs(area2) < 1e-6 or np.any(cr < -1e-9 * np.abs(e).max() ** 2):
        raise OptimizeError(f"{what}: a terrain feature must be a convex polygon with an area")
    return a


def _number(props: dict[str, Any], key: str, what: str, default: float | None = None,
            lo: float = -math.inf, hi: float = math.inf) -> float:
    v = props.get(key, default)
    if v is None:
        raise OptimizeError(f"{what}: property {key} is required")
    try:
        bad = isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi
    except OverflowError:  # an integer beyond any float
        bad = True
    if bad:
        v = v if not isinstance(v, int) or abs(v) < 10**20 else f"an integer of {len(str(abs(v)))} digits"
        raise OptimizeError(f"{what}: property {key} must be a number between {lo:g} and {hi:g}, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class Terrain:
    """The lot's terrain features (none: a flat lot)."""

    features: tuple[Feature, ...] = ()

    @staticmethod
    def feature(role: str, ring: np.ndarray, props: dict[str, Any], what: str) -> Feature:
        """A feature from its GeoJSON properties (see the module docstring)."""
        poly = _convex_ccw(ring, what)
        if role in ("ramp", "bank"):
            slope = math.tan(math.radians(_number(props, "slope_deg", what, lo=0.0, hi=20.0)))
            d = math.radians(_number(props, "uphill_deg", what, lo=-360.0, hi=360.0))
            return Feature(role, poly, (math.cos(d), math.sin(d)), slope=slope)
        d = math.radians(_number(props, "across_deg", what, lo=-360.0, hi=360.0))
        return Feature(role, poly, (math.cos(d), math.sin(d)),
                       height_m=_number(props, "height_m", what, lo=0.0, hi=0.3),
                       max_speed_mps=_number(props, "max_speed_mps", what, BUMP_SPEED_MPS, 0.5, 15.0))

    def __bool__(self) -> bool:
        return bool(self.features)

    @staticmethod
    def weight(f: Feature, x, y):
        """The smooth indicator of ``f``'s polygon at (x, y) (1 inside, 0 outside)."""
        w = 1.0
        a = f.polygon_m
        for i in range(len(a)):
            p, q = a[i], a[(i + 1) % len(a)]
            e = q - p
            n = np.array([-e[1], e[0]]) / np.linalg.norm(e)  # inward normal (counter-clockwise)
            d = n[0] * (x - p[0]) + n[1] * (y - p[1])
            w = w * 0.5 * (1 + ca.tanh(d / EDGE_SOFTNESS_M))
        return w

    def slope(self, x, y):
        """The slope field (∂h/∂x, ∂h/∂y) at (x, y): CasADi expressions (SX or MX) or numbers."""
        sx, sy = 0.0, 0.0
        for f in self.features:
            w = self.weight(f, x, y)
            dx, dy = f.direction
            if f.role == "bump":
                s0, s1 = f.extent_along()
                L = s1 - s0
                s = dx * x + dy * y - s0
                mag = f.height_m * math.pi / L * ca.sin(2 * math.pi * s / L)  # d/ds of H sin²(πs/L)
            else:
                mag = f.slope
            sx = sx + w * mag * dx
            sy = sy + w * mag * dy
        return sx, sy

    def grade_bank(self, x, y, psi):
        """Grade (positive uphill) and bank (positive left side up) [rad] heading ``psi``."""
        sx, sy = self.slope(x, y)
        c, s = ca.cos(psi), ca.sin(psi)
        return ca.atan(sx * c + sy * s), ca.atan(-sx * s + sy * c)

    def grade_bank_np(self, xy: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`grade_bank` at points (n, 2) and headings (n,), as numpy arrays."""
        if not self.features:
            z = np.zeros(len(xy))
            return z, z.copy()
        q = ca.SX.sym("q", 3)
        g, b = self.grade_bank(q[0], q[1], q[2])
        f = ca.Function("gb", [q], [ca.vertcat(g, b)]).map(len(xy))
        out = np.array(f(np.column_stack([xy[:, :2], psi]).T))
        return out[0], out[1]

    def speed_limits(self, u, x, y):
        """Optimizer constraints ``u·w_f(x, y) ≤ cap`` of every bump, as (expression, cap)."""
        return [(u * self.weight(f, x, y), f.max_speed_mps) for f in self.features
                if f.max_speed_mps is not None]

    def violations(self, p_W: np.ndarray, psi: np.ndarray, speed: np.ndarray, grade: np.ndarray,
                   bank: np.ndarray, t_s: np.ndarray) -> list[str]:
        """Where a drive's grade or bank differs from the terrain under it by more than 1°, or
        it crosses a bump faster than allowed."""
        out = []
        g, b = self.grade_bank_np(p_W[:, :2], psi)
        for what, have, want in (("grade", grade, g), ("bank", bank, b)):
            err = np.abs(have - want)
            if err.max(initial=0.0) > np.radians(1.0):
                k = int(np.argmax(err))
                out.append(f"terrain: the drive's {what} {np.degrees(have[k]):.1f}° differs from the lot's "
                           f"{np.degrees(want[k]):.1f}° at t={t_s[k]:.2f} s (x={p_W[k, 0]:.1f} m, y={p_W[k, 1]:.1f} m)")
        for f in self.features:
            if f.max_speed_mps is None:
                continue
            on = f.contains(p_W[:, :2]) & (speed > f.max_speed_mps * (1 + 1e-3))
            if on.any():
                k = int(np.argmax(np.where(on, speed, -1)))
                out.append(f"terrain: crosses a bump at {speed[k]:.2f} m/s (at most {f.max_speed_mps:g}) "
                           f"at t={t_s[k]:.2f} s")
        return out
