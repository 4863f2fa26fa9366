"""The optimizer's CasADi model of car rig (four CAN wheel speeds, the steering angle, a radar) is the evaluator's
information, with no change to the model for the car's kinds."""

from __future__ import annotations

import numpy as np
import pytest
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from helpers import model_samples


@pytest.fixture(scope="module")
def rig():
    return load_rig("sedan")


@pytest.fixture(scope="module")
def traj(rig):
    t = np.linspace(0.0, 40.0, 81)
    prof = ControlProfile(t, 6 + 3 * np.sin(t / 4), 0.08 * np.sin(t / 3), grade_rad=0.03 * np.sin(t / 5))
    return drive(prof, rig.suspension)


NEW = ("wheel.scale_fl", "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset",
       "wheel.time_offset", "radar_front.rot_z", "radar_front.trans_x", "radar_front.time_offset")


def test_the_optimizers_model(rig, traj):
    from excite.factors.base import Nominal
    from excite.information import elimination, problem
    from excite.plan.model import build_model, coarse_rig

    coarse = coarse_rig(rig, 2.0, 4)
    nom = Nominal.of(traj, coarse)
    _, args = model_samples(traj, coarse)
    Lam = np.array(build_model(coarse, nom.n_keyframes).marginal(*args))
    ref = elimination.marginal(problem.build(nom, coarse))
    assert np.abs(Lam - ref).max() <= 1e-6 * np.abs(ref).max()
    for n_ in NEW:
        assert ref[coarse.index(n_), coarse.index(n_)] > 0
