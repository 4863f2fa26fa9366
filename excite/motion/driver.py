"""How a person drives a course: a driver model that turns one plan into the distribution of drives
it produces.

A calibration drive is driven by hand, before the sensors are calibrated: the driver follows
cones and a sheet of instructions ("figure-eight around cones 1 and 2 at 30 km/h, 3 laps"), not a
control file. :func:`drive_course` is one such driver on a :class:`~excite.motion.course.Course`:

- **Speed.** The driver holds the instructed speed with an error that stays over a leg
  (``speed_bias_sigma``) and a slow, smooth fluctuation within it (``speed_noise_sigma``,
  correlation ``speed_noise_time_s`` at the leg's speed), and accelerates and brakes "hard" at a fraction of what was asked that
  varies from leg to leg (``effort_mean`` ± ``effort_sigma``). Their speed profile along the path is
  the fastest one within those (:func:`~excite.motion.paths.plan_speed`), from rest to rest, and
  where they stop follows from it (the fluctuation moves the stops by ~1 m).
- **Steering.** The driver aims at a line beside the planned path, off by a smooth random lateral
  offset (``lateral_sigma_m``, correlation length ``lateral_correlation_m``: nobody drives a cone
  course on the centimetre), and steers towards it as a preview driver does: the path's curvature
  ahead (by the reaction time, which the preview compensates) plus a correction of the lateral
  and heading errors ``ey``, ``eh``: ``κ = κ_path − (ω²/v²)·ey − (2ζω/v)·eh`` with the natural
  frequency ω = ``bandwidth_rad_s`` and the damping ζ = ``damping_ratio``, acted on
  ``reaction_s`` late, the curvature changing no faster and no further than the vehicle allows.
  The curvature is a lateral acceleration v²κ, so on a straight at constant speed and without
  the delay the lateral error obeys ``ey'' + 2ζω·ey' + ω²·ey = 0``. The lag turns into late
  turn-ins and corner cutting where the curvature changes, as in people.

Default values and where they come from (every one is a field of :class:`DriverModel`):

| parameter | default | reasoning |
|---|---|---|
| ``lateral_sigma_m`` | 0.5 m | The standard deviation of lateral position of sober drivers in lanes is 0.18–0.25 m on motorways (the SDLP of on-the-road driving tests); a cone course has no lane to hold, only cones 10–20 m apart, so twice that. 2σ = 1 m: the issue's "a driver 1 m off". |
| ``lateral_correlation_m`` | 25 m | a weave in lane keeping lasts seconds (lateral position's spectrum below ~0.3 Hz); 25 m is 2.5 s at 10 m/s: long enough to take a circle wider or narrower for a quarter lap. |
| ``speed_bias_sigma`` | 5 % | a driver holding a speed by the speedometer: speedometers read 0–10 % high (UNECE R39 allows 0 to +10 % + 4 km/h) and people hold a target within a few km/h. 2σ = 10 %: "10 % of speed off". |
| ``speed_noise_sigma`` | 3 %, over 5 s | speed maintenance without cruise control wanders by 1–2 km/h at 50 km/h over seconds. |
| ``effort_mean``, ``effort_sigma`` | 0.85, 0.1 | asked to "accelerate hard" / "brake hard" within a stated limit, test drivers stay under it: a fraction of the asked acceleration, varying from run to run (clipped to 0.5–1.05). |
| ``reaction_s`` | 0.3 s (±30 % per drive) | the effective time delay of a human in a tracking task is 0.2–0.4 s (the crossover model's τe); a driver who sees the course ahead anticipates the rest (preview). |
| ``bandwidth_rad_s`` | 1.2 rad/s | Drivers keep to a line with two nested loops (Weir & McRuer, "A theory for driver steering control of motor vehicles", HRR 247, 1968; "Dynamics of driver vehicle steering control", Automatica 6, 1970; McRuer, Allen, Weir & Klein, "New results in driver steering control models", Human Factors 19(4), 1977): heading inside, closed at the crossover model's few rad/s, lateral position outside it, closed lower, at about 1 rad/s (~0.15 Hz). This law is that pair: its heading loop closes at 2ζω = 1.7 rad/s and its lateral loop at ω/(2ζ) = 0.86 rad/s (0.6 rad/s would close the lateral loop at 0.37 rad/s and leave a 1 m offset standing for 5 s). With the delay: the open loop crosses over at 1.54ω = 1.85 rad/s with 65° of phase margin, of which 0.3 s takes 32° (the slowest drivers' 0.47 s, 53°). A lane change takes 5–6 s (Toledo & Zohar, "Modeling duration of lane changes", TRR 1999, 2007) against this loop's 2.4 s to remove 95 % of a 1 m offset: a lane change is planned at a comfortable lateral acceleration (Donges' guidance level, Human Factors 20(6), 1978), an error is corrected by the compensatory loop (his stabilisation level). |
| ``damping_ratio`` | 0.7 | The crossover model (McRuer & Jex 1967) has the human shape the loop like ωc·e^(−jωτ)/(jω) near crossover; this law does so when its lead ω/(2ζ) sits well below its crossover 1.54ω: a factor 2.2 at ζ = 0.7 (4.6 % overshoot without the delay). No driver study gives the lateral error's damping itself, and the delay matters more: the correction of a 1 m offset at 10 m/s overshoots by 5 % with a 0.21 s reaction time and by 16 % with 0.39 s (the ±30 % spread), by 1.5 % without delay at ζ = 0.8. |

:func:`driven` draws many drives of one course, each with its own driver (a seed per drive), and
:func:`course_of` turns a free-form control profile into the course a driver would be given for it
(its path and speeds), so that a free-form plan can be driven by the same model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numba as nb
import numpy as np

from ..errors import LimitError
from .course import Course, Leg
from .paths import PathGeometry, plan_speed
from .vehicle import ControlProfile, Limits

STEP_S = 0.02  # the driver's control loop (50 Hz)


@dataclass(frozen=True)
class DriverModel:
    """How a person drives a course (see the module docstring for every default's reasoning)."""

    lateral_sigma_m: float = 0.5
    lateral_correlation_m: float = 25.0
    speed_bias_sigma: float = 0.05
    speed_noise_sigma: float = 0.03
    speed_noise_time_s: float = 5.0
    effort_mean: float = 0.85
    effort_sigma: float = 0.1
    reaction_s: float = 0.3
    reaction_spread: float = 0.3
    bandwidth_rad_s: float = 1.2
    damping_ratio: float = 0.7

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise LimitError(f"driver.{name} must be a finite number ≥ 0, got {value!r}")
        if (self.bandwidth_rad_s <= 0 or self.damping_ratio <= 0 or self.lateral_correlation_m <= 0
                or self.speed_noise_time_s <= 0):
            raise LimitError("driver.bandwidth_rad_s, damping_ratio, lateral_correlation_m and speed_noise_time_s "
                             "must be positive")
        if self.reaction_s > 2.0:
            raise LimitError(f"driver.reaction_s must be at most 2 s, got {self.reaction_s:g}")

    @classmethod
    def exact(cls) -> "DriverModel":
        """A driver who does exactly what the instructions say (the nominal drive, steered by the
        same controller without delay or offset)."""
        return cls(lateral_sigma_m=0.0, speed_bias_sigma=0.0, speed_noise_sigma=0.0, effort_mean=1.0,
                   effort_sigma=0.0, reaction_s=0.0, reaction_spread=0.0)


def _ou(rng: np.random.Generator, n: int, step: float, corr: float, sigma: float) -> np.ndarray:
    """A stationary first-order Gauss–Markov sequence (σ, correlation ``corr`` in units of
    ``step``) of ``n`` samples."""
    if sigma == 0 or n == 0:
        return np.zeros(n)
    a = math.exp(-step / corr)
    e = rng.normal(0.0, sigma * math.sqrt(1 - a * a), n)
    e[0] = rng.normal(0.0, sigma)
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], e)


def _smooth_ou(rng, n, step, corr, sigma):
    """A Gauss–Markov sequence filtered twice more (so that a lateral offset has a continuous
    slope and curvature), rescaled to ``sigma``."""
    x = _ou(rng, n + 400, step, corr, 1.0)
    from scipy.signal import lfilter

    a = math.exp(-step / (0.3 * corr))
    for _ in range(2):
        x = lfilter([1 - a], [1.0, -a], x)
    # scaled by the filtered process's standard deviation (not this draw's)
    return sigma * x[400:] / _filtered_sd(step / corr)


_SD_CACHE: dict[float, float] = {}


def _filtered_sd(ratio: float) -> float:
    key = round(ratio, 9)
    if key not in _SD_CACHE:
        from scipy.signal import lfilter

        rng = np.random.default_rng(12345)
        x = _ou(rng, 200_000, ratio, 1.0, 1.0)
        a = math.exp(-ratio / 0.3)
        for _ in range(2):
            x = lfilter([1 - a], [1.0, -a], x)
        _SD_CACHE[key] = float(x[2000:].std())
    return _SD_CACHE[key]


@nb.njit(cache=True)
def _steer(px, py, ph, pk, ds, aim, v, dt, x0, y0, h0, k0, delay_n, preview_s, omega, zeta, kmax, krate):
    """The steering loop over one leg (see the module docstring): returns the curvature at every
    step and the end state."""
    n = v.size
    m = px.size
    kap = np.empty(n)
    x, y, h, k = x0, y0, h0, k0
    queue = np.full(delay_n + 1, k0)
    qi = 0
    j = 0
    # the closest reference sample to the start
    best = 1e300
    for i in range(min(m, 200)):
        d = (px[i] - x) ** 2 + (py[i] - y) ** 2
        if d < best:
            best, j = d, i
    for t in range(n):
        u = v[t]
        # progress: the closest sample near the last one
        lo, hi = max(j - 30, 0), min(j + 60, m - 1)
        best = 1e300
        for i in range(lo, hi + 1):
            d = (px[i] - x) ** 2 + (py[i] - y) ** 2
            if d < best:
                best, j = d, i
        c, s = math.cos(ph[j]), math.sin(ph[j])
        ax, ay = px[j] - s * aim[j], py[j] + c * aim[j]  # the aimed line, left of the path by aim
        ey = -(x - ax) * s + (y - ay) * c
        eh = (h - ph[j] + math.pi) % (2 * math.pi) - math.pi
        ue = max(u, 1.0)
        ahead = min(j + int((u * preview_s) / ds), m - 1)
        cmd = pk[ahead] - (omega * omega / (ue * ue)) * ey - (2 * zeta * omega / ue) * eh
        cmd = min(max(cmd, -kmax), kmax)
        queue[qi] = cmd
        qi = (qi + 1) % (delay_n + 1)
        applied = queue[qi]  # the command of delay_n steps ago
        if u > 0.05:
            dk = applied - k
            lim = krate * dt
            if dk > lim:
                dk = lim
            elif dk < -lim:
                dk = -lim
            k += dk
        kap[t] = k
        hm = h + 0.5 * u * k * dt
        x += u * math.cos(hm) * dt
        y += u * math.sin(hm) * dt
        h += u * k * dt
    return kap, x, y, h, k


@dataclass(frozen=True)
class DrivenCourse:
    """One drive of a course: the control profile the driver produced, and per leg when it
    started and ended."""

    profile: ControlProfile
    leg_intervals: list[tuple[float, float]]


def _leg_speed(leg: Leg, limits: Limits, margin: float, bias: float, effort: float,
               noise: np.ndarray, noise_step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The driver's speed along one leg at :data:`STEP_S`: the fastest profile within the
    instructed speeds and ``effort`` × the asked acceleration and braking, then driven
    ``(1 + bias)·(1 + noise(s))`` times as fast at every place ``s`` along the path (time
    stretched, places kept: the stops stay where the cones are)."""
    lim = replace(limits, accel_max_mps2=limits.accel_max_mps2 * effort,
                  decel_max_mps2=limits.decel_max_mps2 * effort)
    plan = plan_speed(leg.path, lim, leg.speed_mps, margin=margin)
    from scipy.interpolate import CubicSpline

    f = (1.0 + bias) * (1.0 + CubicSpline(noise_step_m * np.arange(noise.size), noise)(plan.s_m))
    f = np.maximum(f, 0.2)
    dt = np.diff(plan.t_s)
    t = np.concatenate([[0.0], np.cumsum(dt * 2.0 / (f[1:] + f[:-1]))])
    v = plan.speed_mps * f
    n = max(int(math.floor(t[-1] / STEP_S)) + 1, 2)
    tg = np.arange(n) * STEP_S
    vg = np.interp(tg, t, v)
    vg[-1] = 0.0
    return tg, np.maximum(vg, 0.0)


def drive_course(course: Course, limits: Limits, model: DriverModel = DriverModel(),
                 rng: np.random.Generator | None = None, margin: float = 0.9,
                 duration_s: float | None = None) -> DrivenCourse:
    """One person's drive of ``course`` (see the module docstring): the control profile from the
    first leg's start pose, standstills as the course asks, a standstill at the end up to
    ``duration_s``."""
    rng = np.random.default_rng() if rng is None else rng
    delay = 0.0
    if model.reaction_s > 0:
        spread = model.reaction_spread
        delay = min(model.reaction_s * math.exp(spread * rng.normal() - 0.5 * spread ** 2), 2.0)
    delay_n = int(round(delay / STEP_S))
    x, y, h = course.legs[0].start
    k = 0.0
    ts, vs, ks = [], [], []
    intervals = []
    t0 = 0.0
    for leg in course.legs:
        bias = rng.normal(0.0, model.speed_bias_sigma) if model.speed_bias_sigma else 0.0
        effort = model.effort_mean
        if model.effort_sigma:
            effort = float(np.clip(rng.normal(model.effort_mean, model.effort_sigma), 0.5, 1.05))
        step_m = 1.0
        corr_m = max(model.speed_noise_time_s * float(np.max(leg.speed_mps[np.isfinite(leg.speed_mps)],
                                                               initial=5.0)), 1.0)
        # smooth (a filtered Gauss–Markov process): people change speed gradually, and a kink in the
        # speed would be a jump in the acceleration and the body's pitch
        noise = _smooth_ou(rng, int(leg.path.length_m / step_m) + 2, step_m, corr_m, model.speed_noise_sigma) \
            if model.speed_noise_sigma else np.zeros(int(leg.path.length_m / step_m) + 2)
        t, v = _leg_speed(leg, limits, margin, bias, effort, noise, step_m)
        p = _extended(leg.path)
        ds = float(p.s_m[1] - p.s_m[0])
        aim = np.zeros(p.s_m.size)
        if model.lateral_sigma_m:
            aim = _smooth_ou(rng, p.s_m.size, ds, model.lateral_correlation_m, model.lateral_sigma_m)
        kap, x, y, h, k = _steer(p.xyz_m[:, 0], p.xyz_m[:, 1], p.heading_rad, p.curvature_1pm, ds, aim, v,
                                 STEP_S, x, y, h, k, delay_n, delay, model.bandwidth_rad_s, model.damping_ratio,
                                 limits.curvature_max_1pm, limits.curvature_rate_max_1pms)
        if ts:  # the previous leg's last sample is this one's first (at rest)
            t, v, kap = t[1:], v[1:], kap[1:]
        ts.append(t0 + t)
        vs.append(v)
        ks.append(kap)
        t_end = float(ts[-1][-1])
        m = int(math.floor(max(leg.dwell_s, 0.0) / STEP_S + 1e-9))
        if m > 0:
            ts.append(t_end + STEP_S * np.arange(1, m + 1))
            vs.append(np.zeros(m))
            ks.append(np.full(m, k))
            t_end += m * STEP_S
        intervals.append((t0, t_end))
        t0 = t_end
    t = np.concatenate(ts)
    v = np.concatenate(vs)
    kap = np.concatenate(ks)
    if duration_s is not None and duration_s > t[-1] + STEP_S:
        m = int(math.floor((duration_s - t[-1]) / STEP_S + 1e-9))
        t = np.concatenate([t, t[-1] + STEP_S * np.arange(1, m + 1)])
        v = np.concatenate([v, np.zeros(m)])
        kap = np.concatenate([kap, np.full(m, kap[-1])])
    keep = np.arange(0, t.size, 2)  # knots at 25 Hz
    if keep[-1] != t.size - 1:
        keep = np.append(keep, t.size - 1)
    prof = ControlProfile(t[keep], v[keep], kap[keep], start=course.legs[0].start, name=f"{course.name} (driven)")
    return DrivenCourse(prof, intervals)


def _extended(path: PathGeometry, extra_m: float = 30.0) -> PathGeometry:
    """The path continued straight beyond its end (a driver who overshoots a stop still has a
    line to follow)."""
    ds = float(path.s_m[1] - path.s_m[0])
    n = int(math.ceil(extra_m / ds))
    u = ds * np.arange(1, n + 1)
    h = float(path.heading_rad[-1])
    x = path.xyz_m[-1, 0] + u * math.cos(h)
    y = path.xyz_m[-1, 1] + u * math.sin(h)
    return PathGeometry(np.concatenate([path.s_m, path.s_m[-1] + u]),
                        np.vstack([path.xyz_m, np.column_stack([x, y, np.zeros(n)])]),
                        np.concatenate([path.heading_rad, np.full(n, h)]),
                        np.concatenate([path.curvature_1pm, np.zeros(n)]),
                        np.concatenate([path.grade_rad, np.zeros(n)]))


def driven(course: Course, limits: Limits, n: int, seed: int = 0, model: DriverModel = DriverModel(),
           margin: float = 0.9, duration_s: float | None = None) -> list[DrivenCourse]:
    """``n`` drives of ``course``, drive ``i`` by the driver of ``default_rng([seed, i])``."""
    return [drive_course(course, limits, model, np.random.default_rng([seed, i]), margin, duration_s)
            for i in range(n)]


def course_of(profile: ControlProfile, step_m: float = 0.1, name: str | None = None) -> Course:
    """The course a driver is given for a free-form control profile: its path (from the
    profile's own curvature) with its speeds as the instructed speeds, one leg from rest to rest
    split at every stop."""
    from .course import KNOT_RATE_HZ

    t = np.linspace(profile.t_s[0], profile.t_s[-1], int(round(profile.duration_s * 100)) + 1)
    c = profile.at(t)
    v = np.maximum(c["speed_mps"], 0.0)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    moving = v > 0.05
    legs = []
    # split into runs of motion
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    starts = [0] + list(edges + 1)
    h = profile.start[2] + np.concatenate([[0.0], np.cumsum(0.5 * np.diff(t) * (v[1:] * c["curvature_1pm"][1:]
                                                                                 + v[:-1] * c["curvature_1pm"][:-1]))])
    xs = profile.start[0] + np.concatenate([[0.0], np.cumsum(0.5 * np.diff(t) * (v[1:] * np.cos(h[1:]) + v[:-1] * np.cos(h[:-1])))])
    ys = profile.start[1] + np.concatenate([[0.0], np.cumsum(0.5 * np.diff(t) * (v[1:] * np.sin(h[1:]) + v[:-1] * np.sin(h[:-1])))])
    runs = []
    for a, b in zip(starts, starts[1:] + [t.size]):
        if moving[a:b].any() and s[min(b, t.size - 1)] - s[max(a - 1, 0)] > 1.0:
            runs.append((max(a - 1, 0), min(b, t.size - 1)))
    for i, (a, b) in enumerate(runs):
        L = float(s[b] - s[a])
        m = max(int(math.ceil(L / step_m)), 2) + 1
        sg = np.linspace(s[a], s[b], m)
        ss, idx = np.unique(s[a:b + 1], return_index=True)
        sel = a + idx
        path = PathGeometry(sg - sg[0], np.column_stack([np.interp(sg, ss, xs[sel]), np.interp(sg, ss, ys[sel]),
                                                         np.zeros(m)]),
                            np.interp(sg, ss, h[sel]), np.interp(sg, ss, c["curvature_1pm"][sel]), np.zeros(m))
        speed = np.interp(sg, ss, v[sel])
        nxt = runs[i + 1][0] if i + 1 < len(runs) else None
        dwell = 0.0 if nxt is None else float(t[nxt] - t[b])
        legs.append(Leg(path, np.maximum(speed, 0.3), dwell, element=-1, label=f"part {i + 1}"))
    return Course(tuple(legs), name or profile.name)
