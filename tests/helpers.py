"""Factories and invariants the tests share: drives, rigs of every kind, lots, and the invariants
(orientation from integrated rates, specific force from positions) that the trajectory, route and
maneuver tests check. Importable as ``helpers`` from any test (``pythonpath`` in pyproject.toml)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from excite.core import so3
from excite.factors.base import Nominal
from excite.information import dense, problem
from excite.information.closure import marginalise_nuisance
from excite.motion.trajectory import GRAVITY, Trajectory
from excite.motion.vehicle import ControlProfile, Suspension, drive
from excite.rig.config import RIGS_DIR, build_rig, load_rig
from excite.score import spectrum

REPO = Path(__file__).resolve().parents[1]


def weave_profile(duration_s: float = 30.0, name: str = "weave") -> ControlProfile:
    """A gentle drive with varying speed and curvature of both signs (within default limits)."""
    t = np.linspace(0.0, duration_s, int(duration_s * 10) + 1)
    speed = 5.0 + 2.0 * np.sin(2 * np.pi * t / 15.0)
    kappa = 0.05 * np.sin(2 * np.pi * t / 10.0)
    return ControlProfile(t_s=t, speed_mps=speed, curvature_1pm=kappa,
                          grade_rad=0.02 * np.sin(2 * np.pi * t / 20.0), name=name)


def weave_drive(suspension: Suspension = Suspension()) -> Trajectory:
    return drive(weave_profile(), suspension)


def _window(traj: Trajectory, rate_hz: float, window_s: tuple[float, float] | None) -> np.ndarray:
    t = traj.times(rate_hz)
    if window_s is not None:
        t = t[(t >= window_s[0]) & (t <= window_s[1])]
    return t


def orientation_error_from_rates(traj: Trajectory, rate_hz: float = 1000.0,
                                 window_s: tuple[float, float] | None = None) -> float:
    """Integrate the body rate from the first orientation (Exp of RK4-averaged increments) and
    return the largest angle [rad] between the integrated and the sampled orientations."""
    t = _window(traj, rate_hz, window_s)
    dt = 1.0 / rate_hz
    s = traj.sample(t)
    mid = traj.sample(t[:-1] + 0.5 * dt).omega_V
    # RK4-like (Simpson) rate over each step; Exp-product of the increments.
    w = (s.omega_V[:-1] + 4.0 * mid + s.omega_V[1:]) / 6.0
    steps = so3.exp(w * dt)
    R = s.R_W_V[0].copy()
    err = 0.0
    for k in range(steps.shape[0]):
        R = R @ steps[k]
        if (k + 1) % 50 == 0 or k + 1 == steps.shape[0]:
            err = max(err, float(np.linalg.norm(so3.log(s.R_W_V[k + 1].T @ R))))
    return err


def specific_force_error(traj: Trajectory, rate_hz: float = 200.0,
                         window_s: tuple[float, float] | None = None) -> tuple[float, float]:
    """Largest difference [m/s²] between the sampled specific force and Rᵀ(p̈ − g) with p̈ from
    central finite differences of sampled positions at ``rate_hz``, and the largest |f|."""
    t = _window(traj, rate_hz, window_s)[1:-1]
    h = 1.0 / rate_hz
    p = [traj.sample(t + d).p_W_V for d in (-h, 0.0, h)]
    acc = (p[0] - 2 * p[1] + p[2]) / h**2
    s = traj.sample(t)
    f_fd = np.einsum("nji,nj->ni", s.R_W_V, acc - GRAVITY)
    return float(np.abs(f_fd - s.specific_force_V).max()), float(np.abs(s.specific_force_V).max())


# --- a car: the sedan at 5 Hz keyframes, its dense reference ----------------------------------------

T = 30.0


KNOTS = np.linspace(0.0, T, 31)


VARIED_SPEED = 6 + 3 * np.sin(KNOTS / 3)


BOTH_WAYS = 0.08 * np.sin(KNOTS / 5)


def profile(speed, curvature, **kw) -> ControlProfile:
    return ControlProfile(KNOTS, np.broadcast_to(speed, KNOTS.shape) * 1.0,
                          np.broadcast_to(curvature, KNOTS.shape) * 1.0, **kw)


def car_data(radar: bool = False) -> dict:
    """The bundled sedan at 5 Hz keyframes (the dense reference forms J in full), its radar out
    unless asked for."""
    data = yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())
    data.update(keyframe_rate_hz=5)
    data["imu"]["update_rate"] = 100
    if radar:
        data["sensors"][0]["rate_hz"] = 5
    else:
        data["sensors"] = []
        data["targets"] = {k: v for k, v in data["targets"].items() if not k.startswith("*.rot") and
                           not k.startswith("*.trans")}
    return data


def dense_analysis(traj, rig):
    """The dense reference (J and H formed in full, numpy's Schur complement), nuisances
    marginalised, analysed as the evaluator analyses: (spectrum, Λ over the scored coordinates)."""
    prob = problem.build(Nominal.of(traj, rig), rig)
    Lam = dense.marginal_dense(prob)
    J, _ = dense.jacobian(prob)
    before = np.asarray(J[:, prob.n_states:].multiply(J[:, prob.n_states:]).sum(axis=0)).ravel()
    scored = np.array([not c.nuisance for c in rig.coordinates])
    L = marginalise_nuisance(Lam, scored)
    return spectrum.analyse(L, before[scored], np.array([c.target for c in rig.scored])), L


def null_weights(spec, rig) -> dict[str, float]:
    N = spec.null_space
    return {c.name: float((N[i] ** 2).sum()) for i, c in enumerate(rig.scored)}


# --- a GNSS antenna on the robotaxi -----------------------------------------------------------------

LEVER = [0.2, 0.3, 1.5]


def gnss_entry(rate_hz=10.0, tau=30.0, h=0.02, v=0.04, **extra):
    return {"name": "gnss", "kind": "gnss", "rate_hz": rate_hz, "T_B_S": {"translation_m": LEVER},
            "noise": {"horizontal_sigma_m": h, "vertical_sigma_m": v, "correlation_time_s": tau}, **extra}


def gnss_rig(rate_hz=10.0, tau=30.0, suspension=True, lidar=False, constant_biases=False, **entry):
    """The bundled rig's IMU and wheels with a GNSS antenna (and the lidar if asked): keyframes at 10 Hz."""
    base = load_rig("robotaxi").config.model_dump()
    data = dict(base, keyframe_rate_hz=10.0)
    data["sensors"] = ([base["sensors"][0]] if lidar else []) + [gnss_entry(rate_hz, tau, **entry)]
    data["targets"] = {k: v for k, v in base["targets"].items() if lidar or k != "*.rot_*"}
    if not data["sensors"][-1].get("estimate", {}).get("time_offset", True) and not lidar:
        del data["targets"]["*.time_offset"]
    if not suspension:
        data["vehicle"] = dict(data["vehicle"], suspension={"pitch_deg_per_mps2": 0.0, "roll_deg_per_mps2": 0.0})
    if constant_biases:
        data["imu"] = dict(data["imu"], bias_model="constant")
    return build_rig(data)


def sigmas(rep) -> dict[str, float | None]:
    return {p.name: p.sigma for p in rep.parameters}


# --- the optimizer's CasADi model fed with a drive's samples ----------------------------------------

def _colmajor(R: np.ndarray) -> np.ndarray:
    return R.transpose(0, 2, 1).reshape(len(R), 9).T


def model_samples(traj, crig):
    """(keyframes, the body samples Nominal.of takes for ``crig``, in the CasADi model's layout);
    the other surfaces' tests feed the optimizer's model with them too."""
    n = int(round(crig.config.imu.update_rate / crig.keyframe_rate_hz))
    K = Nominal.of(traj, crig).n_keyframes
    t = traj.t_start + np.arange((K - 1) * n + 1) / crig.config.imu.update_rate
    s = traj.sample(t)
    pose = crig.config.vehicle.T_V_B
    b = s.body(pose.R, pose.p)
    return K, [_colmajor(b.R_W_B), b.p_W_B.T, b.v_W.T, b.omega_B.T, b.specific_force_B.T, _colmajor(s.R_V_A)]


# --- drives -----------------------------------------------------------------------------------------

def hilly(profile: ControlProfile) -> ControlProfile:
    """Undulating ground (as benchmarks/bench_validate.py): pitch and roll excitation for the
    vertical lever arms."""
    t = np.linspace(0.0, profile.t_s[-1], int(profile.t_s[-1] * 20) + 1)
    c = profile.at(t)
    return ControlProfile(t, c["speed_mps"], c["curvature_1pm"], grade_rad=0.08 * np.sin(2 * np.pi * t / 4.0),
                          bank_rad=0.06 * np.sin(2 * np.pi * t / 3.0), name="hilly_figure_eight")


# --- an L-shaped lot in GeoJSON, with a hole and a ramp ---------------------------------------------

ORIGIN = (11.58, 48.14)  # lon, lat of the test lot's local origin


L_OUTER = [(0, 0), (70, 0), (70, 30), (30, 30), (30, 66), (0, 66)]  # an L, metres east/north


HOLE = [(44, 9), (56, 9), (56, 19), (44, 19)]  # a building in the long arm


RAMP = [(4, 36), (26, 36), (26, 54), (4, 54)]  # in the short arm, rising to the north


def lot_projection(origin, inverse=False):
    from pyproj import Transformer

    crs = f"+proj=tmerc +lat_0={origin[1]} +lon_0={origin[0]} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m"
    return Transformer.from_crs(crs, "EPSG:4326", always_xy=True) if inverse else \
        Transformer.from_crs("EPSG:4326", crs, always_xy=True)


def _lonlat(ring):
    a = np.array(list(ring) + [ring[0]], dtype=float)
    lon, lat = lot_projection(ORIGIN, inverse=True).transform(a[:, 0], a[:, 1])
    return [[float(x), float(y)] for x, y in zip(lon, lat)]


def l_lot(ramp: bool) -> dict:
    feats = [{"type": "Feature", "properties": {"role": "lot"},
              "geometry": {"type": "Polygon", "coordinates": [_lonlat(L_OUTER), _lonlat(HOLE)]}}]
    if ramp:
        feats.append({"type": "Feature", "properties": {"role": "ramp", "slope_deg": 8.0, "uphill_deg": 90.0},
                      "geometry": {"type": "Polygon", "coordinates": [_lonlat(RAMP)]}})
    return {"type": "FeatureCollection", "features": feats}

