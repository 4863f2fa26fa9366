"""The nominal motion of a drive.

A :class:`Trajectory` is the continuous-time motion of the vehicle frame V (rear-axle centre,
x forward, y left, z up, attached to the sprung body) in the world W (z up). Everything the
information model needs is sampled from it at any rate: pose, world velocity and acceleration,
body angular rate and acceleration, the specific force a perfect IMU would measure, the forward
speed and yaw rate of the rear axle, and left/right wheel angular speeds.

Besides the body pose, a trajectory carries the *suspension tilt*: the rotation ``R_V_A`` of the
road-aligned axle frame A relative to the body. Braking pitches the body nose-down and cornering
rolls it outwards while the axle stays on the road; the non-holonomic constraint and the wheel
odometry act in A. Logged trajectories have no tilt information and use ``R_V_A = I``.

Position is a quintic spline whose derivatives are exact (``v = ṗ``, ``a = p̈``), orientation a
cubic :class:`scipy.spatial.transform.RotationSpline` whose body rates integrate back to the
orientation.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, PPoly, make_interp_spline
from scipy.spatial.transform import Rotation, RotationSpline

from ..core import bounds
from ..errors import RouteError

# Built once per trajectory on first use: the evaluator's two sweeps sample a drive at once, and
# each would build the acceleration's piecewise polynomial otherwise (43 ms of CPU for a
# 10-minute drive)
_FIRST_USE = threading.Lock()

GRAVITY = np.array([0.0, 0.0, -9.80665])


@dataclass(frozen=True)
class MotionSamples:
    """The vehicle frame's nominal motion at times ``t`` (all arrays share the leading axis).

    ``R_W_V, p_W_V``: pose of V in W. ``v_W, a_W``: world velocity and acceleration of V's origin.
    ``omega_V, alpha_V``: body angular rate and angular acceleration, in V. ``R_V_A``: suspension
    tilt (road-aligned axle frame A in V).
    """

    t: np.ndarray
    R_W_V: np.ndarray
    p_W_V: np.ndarray
    v_W: np.ndarray
    a_W: np.ndarray
    omega_V: np.ndarray
    alpha_V: np.ndarray
    R_V_A: np.ndarray

    @property
    def R_W_A(self) -> np.ndarray:
        return np.einsum("nij,njk->nik", self.R_W_V, self.R_V_A)  # (a stack of 3×3: not per-matrix BLAS calls)

    @property
    def speed(self) -> np.ndarray:
        """Forward speed of the rear axle along the road frame's x axis [m/s]."""
        return np.einsum("nji,nj->ni", self.R_W_A, self.v_W)[:, 0]

    @property
    def yaw_rate(self) -> np.ndarray:
        """Yaw rate about the road normal (A's z axis) [rad/s]."""
        return np.einsum("nji,nj->ni", self.R_V_A, self.omega_V)[:, 2]

    @property
    def accel_long(self) -> np.ndarray:
        """Longitudinal acceleration along A's x axis [m/s²]."""
        return np.einsum("nji,nj->ni", self.R_W_A, self.a_W)[:, 0]

    @property
    def accel_lat(self) -> np.ndarray:
        """Lateral acceleration along A's y axis [m/s²] (positive to the left)."""
        return np.einsum("nji,nj->ni", self.R_W_A, self.a_W)[:, 1]

    @property
    def specific_force_V(self) -> np.ndarray:
        """What a perfect accelerometer at V's origin measures, in V: ``Rᵀ(a − g)``."""
        return np.einsum("nji,nj->ni", self.R_W_V, self.a_W - GRAVITY)

    def wheel_speeds(self, radius_left: float, radius_right: float, track: float) -> np.ndarray:
        """Left and right wheel angular speeds ``(n, 2)`` [rad/s]."""
        u, r = self.speed, self.yaw_rate
        return np.stack([(u - 0.5 * track * r) / radius_left, (u + 0.5 * track * r) / radius_right], axis=1)

    def body(self, R_V_B: np.ndarray, p_V_B: np.ndarray) -> "BodySamples":
        """Motion of a frame B rigidly attached to V at pose ``(R_V_B, p_V_B)`` (e.g. the IMU)."""
        R_W_B, p_W_B, v_W_B, omega_B = rigid_body(self.R_W_V, self.p_W_V, self.v_W, self.omega_V, R_V_B, p_V_B)
        p_V_B = np.asarray(p_V_B, dtype=float)
        w = self.omega_V
        lever_acc_V = np.cross(self.alpha_V, p_V_B) + np.cross(w, np.cross(w, p_V_B))
        a_W_B = self.a_W + np.einsum("nij,nj->ni", self.R_W_V, lever_acc_V)
        return BodySamples(t=self.t, R_W_B=R_W_B, p_W_B=p_W_B, v_W=v_W_B, a_W=a_W_B, omega_B=omega_B)


def rigid_body(R_W_V: np.ndarray, p_W_V: np.ndarray, v_W: np.ndarray, omega_V: np.ndarray, R_V_B: np.ndarray,
               p_V_B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Orientation, position, world velocity and body rate of a frame B rigidly attached to V at
    pose ``(R_V_B, p_V_B)``, from V's (stacks): ``R_W_V R_V_B``, ``p + R_W_V p_V_B``,
    ``v + R_W_V (ω × p_V_B)`` and ``R_V_Bᵀ ω``."""
    R_V_B = np.asarray(R_V_B, dtype=float)
    p_V_B = np.asarray(p_V_B, dtype=float)
    R_W_B = np.einsum("nij,jk->nik", R_W_V, R_V_B)  # (a stack of 3×3: not a BLAS call per matrix)
    p_W_B = p_W_V + np.einsum("nij,j->ni", R_W_V, p_V_B)
    v_W_B = v_W + np.einsum("nij,nj->ni", R_W_V, np.cross(omega_V, p_V_B))
    return R_W_B, p_W_B, v_W_B, omega_V @ R_V_B


@dataclass(frozen=True)
class BodySamples:
    """Motion of a body-fixed frame B (e.g. the IMU): pose, world velocity/acceleration, body rate."""

    t: np.ndarray
    R_W_B: np.ndarray
    p_W_B: np.ndarray
    v_W: np.ndarray
    a_W: np.ndarray
    omega_B: np.ndarray

    @property
    def specific_force_B(self) -> np.ndarray:
        """What a perfect accelerometer measures, in B: ``Rᵀ(a − g)`` [m/s²]."""
        return np.einsum("nji,nj->ni", self.R_W_B, self.a_W - GRAVITY)


@dataclass(frozen=True)
class SensorLog:
    """What a log recorded of one of the rig's sensors: the times of its messages ``t`` [s, on
    the drive's clock, increasing] and, where the sensor reports one, each message's covariance
    ``covariance`` (n × d × d) in its kind's measurement frame (a GNSS fix: world position, m²;
    a lidar's or camera's odometry: the covariance per second of its increment ending at the
    message, rotation then translation, rad²/s and m²/s, in the world frame:
    :mod:`excite.io.bags.covariance`). A drive that carries a sensor's log is scored with the
    measurements the log holds (a GNSS outage: no fixes), and with the covariances where its rig
    asks for them."""

    t: np.ndarray
    covariance: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or (t.size > 1 and not np.all(np.diff(t) > 0)) or not np.all(np.isfinite(t)):
            raise RouteError("a sensor log's message times must be finite and strictly increasing")
        if self.covariance is not None and np.asarray(self.covariance).shape[:1] != t.shape:
            raise RouteError(f"a sensor log has {t.size} messages and {np.asarray(self.covariance).shape[0]} covariances")

    def shifted(self, dt_s: float) -> "SensorLog":
        return SensorLog(np.asarray(self.t) + dt_s, self.covariance)

    def rotated(self, R: np.ndarray) -> "SensorLog":
        """The log of the same drive rotated by ``R`` in the world (a world-frame covariance rotates,
        each 3-block of a 6 × 6 one: rotation and translation)."""
        if self.covariance is None:
            return SensorLog(self.t, None)
        C = np.asarray(self.covariance)
        Rb = np.kron(np.eye(C.shape[-1] // 3), R)
        return SensorLog(self.t, Rb @ C @ Rb.T)
        return SensorLog(self.t, cov)


@dataclass(frozen=True)
class SceneView:
    """What a scene shows the rig's lidars and cameras along a drive (:func:`excite.scene.along.seen`):
    per sensor name, the times ``t`` of the scans (or camera frame pairs) ray-cast (increasing) and
    each one's information about its relative pose ``H_W`` (S × 6 × 6, [rotation, translation]) in
    world-aligned axes (the sensor's frame turned to the world's: the information does not change
    as the sensor turns in place but looks at the same surfaces), and, for a lidar, the
    information of the road plane fitted to its
    returns from the ground ``G_W`` (S × 4 × 4, [normal, height], the normal's part in
    world-aligned axes). ``digest``: the scene's (equal scenes, equal digests); ``source``: its
    name (a file, a bundled scene), for reports."""

    digest: str
    t: dict[str, np.ndarray]
    H_W: dict[str, np.ndarray]
    G_W: dict[str, np.ndarray]
    source: str = "scene"

    def nearest(self, name: str, t: np.ndarray) -> np.ndarray:
        """The index of the scan ray-cast nearest each of the times ``t`` of ``name``'s."""
        ts = self.t[name]
        if ts.size < 2:
            return np.zeros(np.size(t), dtype=int)
        j = np.clip(np.searchsorted(ts, t), 1, ts.size - 1)
        return np.where(np.abs(ts[j - 1] - t) <= np.abs(ts[j] - t), j - 1, j)

    def shifted(self, dt_s: float) -> "SceneView":
        return SceneView(self.digest, {k: v + dt_s for k, v in self.t.items()}, self.H_W, self.G_W, self.source)


class Trajectory:
    """Continuous nominal motion of the vehicle frame V over ``[t_start, t_end]``.

    Built from poses of V at increasing times ``t``. ``tilt_pitch_roll`` (n, 2) are the
    suspension pitch and roll [rad] of the body relative to the road (none for logged drives);
    ``velocity`` (n, 3), when known, is integrated instead of differentiating the positions, so
    that ``ṗ`` equals the given velocity at the samples. :func:`excite.motion.vehicle.drive` builds one
    from a control profile and the readers in :mod:`excite.io.routes` from files.
    """

    def __init__(self, t: np.ndarray, R_W_V: np.ndarray, p_W_V: np.ndarray,
                 tilt_pitch_roll: np.ndarray | None = None, velocity: np.ndarray | None = None,
                 name: str = "route"):
        t = np.asarray(t, dtype=float)
        if t.ndim != 1 or t.size < 6:
            raise RouteError(f"a trajectory needs at least 6 samples, got {t.size}")
        if not np.all(np.diff(t) > 0):
            raise RouteError("sample times must be strictly increasing")
        if t.size > bounds.MAX_SAMPLES:
            raise RouteError(f"{t.size} samples, over the limit of {bounds.MAX_SAMPLES:,}")
        if not t[-1] - t[0] <= bounds.max_duration_s():
            raise RouteError(f"the drive lasts {t[-1] - t[0]:.6g} s, over the limit of "
                             f"{bounds.max_duration_s():g} s")
        for label, x in (("positions", p_W_V), ("velocities", velocity)):
            if x is not None and not np.all(np.isfinite(x)):
                raise RouteError(f"the drive's {label} are not all finite")
        self._t = t
        self._R = np.asarray(R_W_V, dtype=float)
        self._p = np.asarray(p_W_V, dtype=float)
        self._v = None if velocity is None else np.asarray(velocity, dtype=float)
        self._tilt_samples = None
        if tilt_pitch_roll is not None and np.any(np.asarray(tilt_pitch_roll) != 0):
            self._tilt_samples = np.asarray(tilt_pitch_roll, dtype=float)
        if self._v is None:
            self._pos = make_interp_spline(t, self._p, k=5)
        else:
            pos = make_interp_spline(t, self._v, k=5).antiderivative(1)
            self._pos = BSpline(pos.t, pos.c + (self._p[0] - pos(t[0])), pos.k)
        self._vel = self._pos.derivative(1)
        self._acc = self._pos.derivative(2)
        self._rot = RotationSpline(t, Rotation.from_matrix(self._R))
        self._tilt = None if self._tilt_samples is None else make_interp_spline(t, self._tilt_samples, k=3)
        self._acc_pp = None  # acceleration as PPoly (breakpoints, coefficients), built on first use
        self.t_start = float(t[0])
        self.t_end = float(t[-1])
        self.name = name
        self.logs: dict[str, SensorLog] = {}  # what a log recorded of the rig's sensors, by sensor name
        self.scene: SceneView | None = None  # what a scene shows the rig's lidars and cameras (excite.scene.along.seen)
        # where W's origin lies in the frame the drive's poses were given in: logged poses are
        # re-based on their first position (excite.io.poses.trajectory_from_poses); a scene in
        # that frame is seen from p_W_V + origin
        self.origin = np.zeros(3)

    def with_logs(self, logs: dict[str, SensorLog]) -> "Trajectory":
        """The same drive carrying ``logs`` (by the rig's sensor name) besides its own."""
        out = copy.copy(self)
        out.logs = {**self.logs, **logs}
        return out

    def with_scene(self, view: SceneView | None) -> "Trajectory":
        """The same drive seeing a scene (``view``: :func:`excite.scene.along.seen`; None: none)."""
        out = copy.copy(self)
        out.scene = view
        return out

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start

    @property
    def has_tilt(self) -> bool:
        """Whether the drive carries suspension tilt (generated drives do, logged ones do not)."""
        return self._tilt is not None

    def times(self, rate_hz: float) -> np.ndarray:
        """A uniform grid at ``rate_hz`` that starts at ``t_start`` and stays within the drive."""
        n = int(np.floor(self.duration * rate_hz + 1e-9)) + 1
        return self.t_start + np.arange(n) / rate_hz

    def rotation(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Orientation of V at ``t`` (clipped to the drive), its body rate and angular acceleration: the cubic
        rotation-vector spline of ``RotationSpline`` (R = R_k·Exp(φ(t)) on segment k), evaluated
        in one compiled loop (:func:`excite.motion.kernels.rotation_samples`) rather than through scipy's
        rotation objects."""
        from . import kernels

        t = np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end)
        rot = self._rot.interpolator
        return kernels.rotation_samples(t, _segments(rot.x, t), rot.x, rot.c, self._R)

    def sample(self, t: np.ndarray) -> MotionSamples:
        """The motion at times ``t`` (clipped to the drive)."""
        t = np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end)
        R, omega, alpha = self.rotation(t)
        p, v, R_V_A = self.translation(t)
        return MotionSamples(t=t, R_W_V=R, p_W_V=p, v_W=v, a_W=self._acc(t), omega_V=omega, alpha_V=alpha,
                             R_V_A=R_V_A)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """World velocity of V at ``t`` (clipped to the drive)."""
        return self._vel(np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end))

    def translation(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position ``p_W_V`` and world velocity of V and the suspension tilt ``R_V_A`` at ``t``
        (clipped to the drive): :meth:`sample` without the rotation and the acceleration."""
        t = np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end)
        if self._tilt is None:
            R_V_A = np.broadcast_to(np.eye(3), (t.size, 3, 3)).copy()
        else:
            pr = self._tilt(t)  # R_V_A = (R_y(pitch) R_x(roll))ᵀ, written out
            cp, sp, cr, sr = np.cos(pr[:, 0]), np.sin(pr[:, 0]), np.cos(pr[:, 1]), np.sin(pr[:, 1])
            R_V_A = np.zeros((t.size, 3, 3))
            R_V_A[:, 0, 0], R_V_A[:, 0, 2] = cp, -sp
            R_V_A[:, 1, 0], R_V_A[:, 1, 1], R_V_A[:, 1, 2] = sp * sr, cr, cp * sr
            R_V_A[:, 2, 0], R_V_A[:, 2, 1], R_V_A[:, 2, 2] = sp * cr, -sr, cp * cr
        return self._pos(t), self._vel(t), R_V_A

    def imu(self, t: np.ndarray, R_V_B: np.ndarray, p_V_B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What a perfect IMU at pose ``(R_V_B, p_V_B)`` in V sees at ``t``: its orientation
        ``R_W_B``, body rate ``ω_B`` and specific force ``f_B = R_W_Bᵀ(a_B − g)`` with the lever-arm
        acceleration ``α × p + ω × (ω × p)``. The same splines as :meth:`sample`, evaluated in one
        compiled loop (:func:`excite.motion.kernels.imu_samples`): this runs at the IMU rate."""
        from . import kernels

        t = np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end)
        rot = self._rot.interpolator
        if self._acc_pp is None:
            with _FIRST_USE:
                if self._acc_pp is None:
                    parts = [PPoly.from_spline(BSpline(self._acc.t, self._acc.c[:, j], self._acc.k)) for j in range(3)]
                    self._acc_pp = (parts[0].x, np.stack([pp.c for pp in parts], axis=-1))
        x_acc, c_acc = self._acc_pp
        return kernels.imu_samples(t, _segments(rot.x, t), rot.x, rot.c, self._R, _segments(x_acc, t), x_acc, c_acc,
                                   GRAVITY,
                                   np.ascontiguousarray(R_V_B, dtype=float), np.asarray(p_V_B, dtype=float))

    def transformed(self, R: np.ndarray, p: np.ndarray, name: str | None = None) -> "Trajectory":
        """The same drive moved rigidly in the world: ``x ↦ R x + p``.

        Only rotations about the vertical keep gravity where it was; the information model is
        invariant under exactly those and under translations. A scene it saw stays behind (move
        the scene with it and look again: :func:`excite.scene.along.seen`).
        """
        R = np.asarray(R, dtype=float)
        v = None if self._v is None else self._v @ R.T
        out = Trajectory(self._t, R @ self._R, self._p @ R.T + np.asarray(p, dtype=float),
                         tilt_pitch_roll=self._tilt_samples, velocity=v, name=name or self.name)
        out.origin = R @ self.origin
        return out.with_logs({k: log.rotated(R) for k, log in self.logs.items()})

    def shifted(self, dt_s: float) -> "Trajectory":
        """The same drive with every time stamp moved by ``dt_s``."""
        out = Trajectory(self._t + dt_s, self._R, self._p, tilt_pitch_roll=self._tilt_samples,
                         velocity=self._v, name=self.name)
        out.origin = self.origin
        out = out.with_logs({k: log.shifted(dt_s) for k, log in self.logs.items()})
        return out.with_scene(None if self.scene is None else self.scene.shifted(dt_s))

    def cropped(self, t_start: float, t_end: float, name: str | None = None) -> "Trajectory":
        """The same motion restricted to ``[t_start, t_end]`` (within the drive): the same splines,
        so every sample inside the window is the whole drive's, bit for bit."""
        if not self.t_start <= t_start < t_end <= self.t_end:
            raise RouteError(f"window {t_start:.6g} … {t_end:.6g} s is not inside the drive "
                             f"({self.t_start:.6g} … {self.t_end:.6g} s)")
        out = copy.copy(self)
        out.t_start, out.t_end = float(t_start), float(t_end)
        out.name = name or self.name
        return out

    def length_m(self, rate_hz: float = 20.0) -> float:
        """Path length of the rear axle [m]."""
        s = self.sample(self.times(rate_hz))
        return float(np.trapezoid(np.linalg.norm(s.v_W, axis=1), s.t))


def _segments(breaks: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the piecewise-polynomial segment (between ``breaks``) that holds every time
    (compiled: :func:`excite.motion.kernels.segments`)."""
    from . import kernels

    return kernels.segments(np.ascontiguousarray(breaks, dtype=float), np.ascontiguousarray(t, dtype=float))
