"""Lidar and camera odometry noise that does not depend on the frame rate (issue 27).

The odometry's noise is a drift density (σ of a relative pose over Δt = density·√Δt): a lidar of
the same quality at 10, 20 or 40 Hz is told the same σ, and rigs with the old per-pair keys are
refused with the density that keeps their numbers at their sensor's rate.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from excite.errors import RigError
from excite.factors.odometry import pair_sigmas
from excite.io.routes import read_route
from excite.rig.config import build_rig, load_rig
from excite.score.evaluate import evaluate

TRAJ = Path(__file__).resolve().parents[1] / "trajectories"


def _lidar_at(rate_hz: float):
    base = load_rig("robotaxi")
    sensors = base.config.model_dump()["sensors"]
    sensors[0]["rate_hz"] = rate_hz  # the camera stays at 10 Hz, every 1/2/4 keyframes
    return base.with_config(keyframe_rate_hz=rate_hz, sensors=sensors)


def test_a_faster_lidar_of_the_same_density_is_told_the_same_sigma():
    traj = read_route(TRAJ / "slalom.tum")
    sigma = {}
    for f in (10.0, 20.0, 40.0):
        rep = evaluate(traj, _lidar_at(f))
        sigma[f] = {p.name: p.sigma for p in rep.parameters}
    for name, s10 in sigma[10.0].items():
        for f in (20.0, 40.0):
            assert sigma[f][name] == pytest.approx(s10, rel=0.03), (name, f, sigma[f][name], s10)


def test_the_per_pair_sigma_is_the_density_times_root_dt():
    rig = _lidar_at(40.0)
    lidar = rig.config.sensors[0]
    sig_r, sig_t = pair_sigmas(lidar)
    assert sig_t == pytest.approx(lidar.noise.translation_density_m_per_sqrt_s * math.sqrt(1 / 40.0), rel=1e-15)
    assert sig_r == pytest.approx(math.radians(lidar.noise.rotation_density_deg_per_sqrt_s) / math.sqrt(40.0), rel=1e-15)
    # the bundled rig's densities are its old per-pair σ at 10 Hz, exactly
    assert pair_sigmas(load_rig("robotaxi").config.sensors[0]) == (math.radians(0.05), 0.02)


@pytest.mark.parametrize("old, new, factor", [("rotation_sigma_deg", "rotation_density_deg_per_sqrt_s", 0.05),
                                              ("translation_sigma_m", "translation_density_m_per_sqrt_s", 0.02)])
def test_the_old_per_pair_keys_give_the_equivalent_density(old, new, factor):
    data = load_rig("robotaxi").config.model_dump()
    data["sensors"][1]["rate_hz"] = 20.0
    data["keyframe_rate_hz"] = 20.0
    data["sensors"][1]["noise"] = {old: factor}
    with pytest.raises(RigError) as err:
        build_rig(data)
    msg = str(err.value)
    assert msg.startswith(f"sensors.1.noise.{old}: ")
    assert f"sensors.1.noise.{new}" in msg and "20 Hz" in msg
    want = f"{factor * math.sqrt(20.0):.6g}"
    assert f"{new}: {want}" in msg, msg
    # the value it names keeps the old σ per pair
    data["sensors"][1]["noise"] = {"rotation_density_deg_per_sqrt_s": 1.0, "translation_density_m_per_sqrt_s": 1.0,
                                   new: float(want)}
    s = build_rig(data).config.sensors[1]
    got = pair_sigmas(s)[0 if old.startswith("rotation") else 1]
    assert got == pytest.approx(math.radians(factor) if old.startswith("rotation") else factor, rel=1e-5)
