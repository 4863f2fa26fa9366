"""Live guidance of car rig (four CAN wheel speeds, the steering angle, a radar) ends at the evaluator's answer."""

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


@pytest.fixture(scope="module")
def report(rig, traj):
    return evaluate(traj, rig)


def _sigma(Lam, rig, name):
    from excite.information.closure import marginalise_nuisance

    scored = np.array([not c.nuisance for c in rig.coordinates] + [True] * (Lam.shape[0] - len(rig.coordinates)))
    L = marginalise_nuisance(Lam, scored)
    i = [c.name for c in rig.scored].index(name)
    return float(np.sqrt(np.linalg.inv(L)[i, i]))


NEW = ("wheel.scale_fl", "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset",
       "wheel.time_offset", "radar_front.rot_z", "radar_front.trans_x", "radar_front.time_offset")


def test_live_guidance(rig, traj, report):
    from excite.score.live import Incremental, chunks

    inc = Incremental(rig)
    for c in chunks(traj, rig):
        inc.append(c)
    Lam = inc.information().information
    sig = {p.name: p.sigma for p in report.parameters}
    for n in NEW:
        assert _sigma(Lam, rig, n) == pytest.approx(sig[n], rel=1e-7), n
