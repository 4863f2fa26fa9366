"""Mining a car's drive (four CAN wheel speeds, the steering angle, a radar): a window's σ is the evaluator's."""

from __future__ import annotations

import numpy as np
import pytest
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate


@pytest.fixture(scope="module")
def rig():
    return load_rig("sedan")


@pytest.fixture(scope="module")
def traj(rig):
    t = np.linspace(0.0, 40.0, 81)
    prof = ControlProfile(t, 6 + 3 * np.sin(t / 4), 0.08 * np.sin(t / 3), grade_rad=0.03 * np.sin(t / 5))
    return drive(prof, rig.suspension)


def _sigma(Lam, rig, name):
    from excite.information.closure import marginalise_nuisance

    scored = np.array([not c.nuisance for c in rig.coordinates] + [True] * (Lam.shape[0] - len(rig.coordinates)))
    L = marginalise_nuisance(Lam, scored)
    i = [c.name for c in rig.scored].index(name)
    return float(np.sqrt(np.linalg.inv(L)[i, i]))


NEW = ("wheel.scale_fl", "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset",
       "wheel.time_offset", "radar_front.rot_z", "radar_front.trans_x", "radar_front.time_offset")


def test_mining(rig, traj):
    from excite.fleet import mine

    s = mine.summarise(traj, rig, chunk_s=10.0)
    Lam, _ = mine.window_information(s, 2, first=1)  # chunks 1 and 2
    crop = mine.crop(traj, s.time(int(s.edges[1])), s.time(int(s.edges[3])))
    sig = {p.name: p.sigma for p in evaluate(crop, rig).parameters}
    for n in NEW:
        assert _sigma(Lam[0], rig, n) == pytest.approx(sig[n], rel=1e-6), n
