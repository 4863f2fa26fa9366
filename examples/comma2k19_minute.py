"""What one minute of highway tells about a car's CAN wheels, steering and radar: the comma2k19
RAV4 minute scored from its own wheel speeds, steering angle and IMU (the dataset's pose as the
motion), the wheel speeds' agreement with that pose, and the radar's yaw from its stationary
targets. The README's figures come from this script:

    PYTHONPATH=. python3 examples/comma2k19_minute.py [../shared/data/comma2k19_rav4_seg40]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from excite.factors.ackermann import interval_means
from excite.factors.base import Nominal
from excite.io.comma2k19 import can_recording, radar_ego_velocity, read_comma2k19, stationary_detections, trajectory
from excite.rig.config import load_rig
from excite.score.agreement import agreement
from excite.score.evaluate import evaluate

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "data" / "comma2k19_rav4_seg40"
RIG = HERE / "comma2k19_rav4_can.yaml"
WHEELS = ["FL", "FR", "RL", "RR"]


def radar_yaw(rec, traj, rig, selected: np.ndarray) -> dict:
    """The radar's yaw from its stationary detections, the motion held: every detection's range
    rate against ``−s·u(az)ᵀ Rz(ψ)ᵀ v_S`` (v_S the radar's velocity in its nominal frame, from the
    drive and the rig's mounting; s a speed scale between the radar and the pose), least squares
    in (ψ, s); σ of ψ white (the residual's scatter) and cluster-robust by track run (a track's
    detections share their error); and the azimuths' spread, which sets what the model expects."""
    r = rec.radar
    i = np.flatnonzero(selected & (r.t > traj.t_start) & (r.t < traj.t_end))
    entry = next(s for s in rig.config.sensors if s.name == "radar_front")
    pose = rig.config.vehicle.T_V_B
    b = traj.sample(r.t[i]).body(pose.R, pose.p)
    R_BS, p_BS = entry.T_B_S.R, entry.T_B_S.p
    v_S = (np.einsum("nji,nj->ni", b.R_W_B, b.v_W) + np.cross(b.omega_B, p_BS)) @ R_BS
    az = r.azimuth_rad[i]
    x = np.array([0.0, 1.0])  # ψ, s
    for _ in range(4):
        c, s = np.cos(x[0]), np.sin(x[0])
        vx, vy = c * v_S[:, 0] + s * v_S[:, 1], -s * v_S[:, 0] + c * v_S[:, 1]  # Rz(ψ)ᵀ v_S
        base = np.cos(az) * vx + np.sin(az) * vy
        J = np.column_stack([-x[1] * (np.cos(az) * vy - np.sin(az) * vx), -base])
        res = r.range_rate_mps[i] + x[1] * base
        x = x + np.linalg.lstsq(J, res, rcond=None)[0]
    c, s = np.cos(x[0]), np.sin(x[0])
    res = r.range_rate_mps[i] + x[1] * (np.cos(az) * (c * v_S[:, 0] + s * v_S[:, 1]) +
                                        np.sin(az) * (-s * v_S[:, 0] + c * v_S[:, 1]))
    Hinv = np.linalg.inv(J.T @ J)
    white = float(np.sqrt(np.mean(res ** 2) * Hinv[0, 0]))
    # track runs: one address, no gap over 0.2 s
    run = np.zeros(i.size, dtype=int)
    last: dict[int, tuple[float, int]] = {}
    n_runs = 0
    for k, j in enumerate(i):
        a = int(r.address[j])
        if a in last and r.t[j] - last[a][0] < 0.2:
            run[k] = last[a][1]
        else:
            run[k], n_runs = n_runs, n_runs + 1
        last[a] = (float(r.t[j]), int(run[k]))
    scores = np.stack([np.bincount(run, J[:, m] * res) for m in range(2)], axis=1)
    robust = float(np.sqrt((Hinv @ scores.T @ scores @ Hinv)[0, 0]))
    return {"psi_rad": float(x[0]), "scale": float(x[1]), "sigma_white_rad": white, "sigma_runs_rad": robust,
            "detections": int(i.size), "runs": n_runs, "rms_mps": float(np.sqrt(np.mean(res ** 2))),
            "sin2_az": float(np.mean(np.sin(az) ** 2))}


def main(data: Path = DATA) -> None:
    rig = load_rig(RIG)
    rec = read_comma2k19(data)
    traj = trajectory(rec)
    print(f"{rec.name}: {traj.duration:.1f} s, {traj.length_m():.0f} m; IMU {rec.gyro.t.size} samples, "
          f"wheel speeds {rec.wheel_speeds.t.size} ({rec.wheel_speeds.t.size / np.ptp(rec.wheel_speeds.t):.1f} Hz), "
          f"radar {rec.radar.n_cycles} cycles, GNSS {', '.join(f'{k} {g.t.size}' for k, g in rec.gnss.items())}")

    rep = evaluate(traj, rig)
    print(f"\nscore {rep.score:.3g}, rank {rep.rank}/{rep.rank + rep.nullity}")
    for p in rep.parameters:
        ratio = "—" if p.sigma is None else f"{p.sigma / p.target:.3g}"
        print(f"  {p.name:26s} σ {p.sigma!s:>24} target {p.target:.3g}  σ/target {ratio}")

    # the wheel speeds and the steering against the pose
    plain = trajectory(rec, measured_imu=False, cutoff_hz=4.0)
    nom = Nominal.of(plain, rig)
    speeds, steer = interval_means(can_recording(rec), nom.t)
    meas = np.column_stack([speeds, steer])
    fit = [f"wheel.scale_{w}" for w in ("fl", "fr", "rl", "rr")] + ["wheel.time_offset", "steering.offset",
                                                                    "steering.ratio"]
    a = agreement(plain, rig, "ackermann", meas, fit)
    print("\nCAN vs pose (pose smoothed at 4 Hz, 0.1-s means):")
    print("  residual RMS at the nominal calibration: " + ", ".join(
        f"{n} {x:.3f} m/s" for n, x in zip(WHEELS, a.rms_nominal[:4])) + f", steering {np.degrees(a.rms_nominal[4]):.2f}°")
    print("  after fitting scale factors, CAN time offset, steering offset and ratio (pose held): " + ", ".join(
        f"{n} {x:.3f} m/s" for n, x in zip(WHEELS, a.rms_fitted[:4])) + f", steering {np.degrees(a.rms_fitted[4]):.2f}°;"
        f" whitened {a.whitened_rms_nominal:.2f} → {a.whitened_rms_fitted:.2f}")
    for k, v in a.fitted.items():
        s = a.fitted_sigma[k]
        if k == "steering.offset":
            print(f"  {k} = {np.degrees(v):+.3f}° ± {np.degrees(s):.3f}°")
        elif k == "wheel.time_offset":
            print(f"  {k} = {v * 1e3:+.1f} ms ± {s * 1e3:.1f} ms")
        else:
            print(f"  {k} = {v:.4f} ± {s:.4f}")

    # the radar
    sel = stationary_detections(rec)
    r = rec.radar
    per_cycle = np.bincount(r.cycle[sel], minlength=r.n_cycles)
    print(f"\nradar: {sel.sum()} of {r.t.size} detections stationary ({100 * sel.mean():.1f} %; "
          f"|ṙ + v_CAN·cos az| < 0.5 m/s, no new or duplicate track), {per_cycle.mean():.2f} per cycle; cycles with "
          f"≥ 1 / ≥ 2: {100 * np.mean(per_cycle >= 1):.0f} % / {100 * np.mean(per_cycle >= 2):.0f} %")
    y = radar_yaw(rec, traj, rig, sel)
    print(f"  yaw from {y['detections']} detections in {y['runs']} track runs (motion held, a speed scale "
          f"fitted: {y['scale']:.4f}): {np.degrees(y['psi_rad']):+.2f}° ± {np.degrees(y['sigma_white_rad']):.2f}° "
          f"(white) ± {np.degrees(y['sigma_runs_rad']):.2f}° (by track run); residual {y['rms_mps']:.3f} m/s; "
          f"mean sin² az {y['sin2_az']:.4f}")
    ev = radar_ego_velocity(rec, sel)
    rows = np.full((nom.n_keyframes - 1, 2), np.nan)
    k = np.clip(np.round((ev.t - nom.t[0]) * rig.keyframe_rate_hz).astype(int), 0, nom.n_keyframes - 2)
    near = np.abs(nom.t[k] - ev.t) < 0.5 / rig.keyframe_rate_hz
    rows[k[near]] = ev.v_mps[near]
    ra = agreement(plain, rig, "radar_front", rows, ["radar_front.rot_z"])
    print(f"  ego-velocity fits ({near.sum()} cycles with ≥ 2 targets over ≥ 5° at a keyframe): residual RMS "
          f"forward {ra.rms_nominal[0]:.3f}, lateral {ra.rms_nominal[1]:.3f} m/s; their yaw "
          f"{np.degrees(ra.fitted['radar_front.rot_z']):+.2f}° ± {np.degrees(ra.fitted_sigma['radar_front.rot_z']):.2f}°")
    sig = next(p.sigma for p in rep.parameters if p.name == "radar_front.rot_z")
    print(f"  excite's σ of radar_front.rot_z for the minute: {np.degrees(sig):.3f}°")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DATA)
