"""A mined window of a drive with GNSS fixes (an outage in the log) is the evaluator's crop.

A GNSS antenna breaks the gauge (world position and yaw are observed): every consumer closes its
drives through :mod:`excite.information.closure` (world states with the drive's origin, no gauge,
the first fix opening the error's chain), and each must agree with the evaluator."""

from __future__ import annotations

import numpy as np
import pytest
from excite.information.closure import marginalise_nuisance
from excite.information.problem import columns
from excite.motion.maneuvers import figure_eight
from excite.motion.trajectory import SensorLog
from excite.motion.vehicle import drive
from excite.score.evaluate import evaluate
from helpers import gnss_rig, sigmas


def _sigma(Lam, rig, n_drives=1):
    names, nuisance = columns(rig, n_drives)
    L = marginalise_nuisance(Lam, ~nuisance)
    scored = [n for n, nu in zip(names, nuisance) if not nu]
    C = np.linalg.pinv(L)
    return {n: float(np.sqrt(C[i, i])) for i, n in enumerate(scored)}


@pytest.fixture(scope="module")
def rig():
    return gnss_rig(lidar=True)


@pytest.fixture(scope="module")
def traj(rig):
    return drive(figure_eight(40.0), rig.suspension)


@pytest.mark.parametrize("outage", [False, True])
def test_a_mined_window_is_the_evaluators_crop(rig, traj, outage):
    """A window closed as a drive of its own: its own origin, its first fix opening the chain (or,
    where the window starts in an outage, no opening)."""
    from excite.fleet import mine

    log = traj
    if outage:
        t = np.arange(traj.t_start, traj.t_end, 0.1)
        log = traj.with_logs({"gnss": SensorLog(t[(t < traj.t_start + 8) | (t > traj.t_start + 13)])})
    s = mine.summarise(log, rig, chunk_s=10.0)
    Lam, diag = mine.window_information(s, 2, first=1)  # chunks 1 and 2: 10 … 30 s
    crop = mine.crop(log, s.time(int(s.edges[1])), s.time(int(s.edges[3])))
    rep = evaluate(crop, rig)
    got, want = _sigma(Lam[0], rig), sigmas(rep)
    for n in ("gnss.trans_x", "gnss.trans_y", "gnss.time_offset", "lidar.rot_z"):
        assert got[n] == pytest.approx(want[n], rel=1e-6), n
    assert len(columns(rig, 1)[0]) == Lam.shape[1]
