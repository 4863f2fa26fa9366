"""Live guidance of a rig with a GNSS antenna ends at the evaluator's answer, with and
without an outage in the log.

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


def test_live_guidance_ends_at_the_evaluators_answer(rig, traj):
    from excite.score.live import Incremental, chunks

    inc = Incremental(rig)
    for c in chunks(traj, rig):
        inc.append(c)
    got = _sigma(inc.information().information, rig)
    want = sigmas(evaluate(traj, rig))
    for n in ("gnss.trans_x", "gnss.trans_z", "gnss.time_offset", "lidar.trans_z"):
        assert got[n] == pytest.approx(want[n], rel=1e-7), n


def test_live_guidance_with_an_outage_from_the_log(rig, traj):
    """The log's outage and the first fix: the drive so far closes as the evaluator's."""
    from excite.score.live import Incremental, chunks

    t = np.arange(traj.t_start, traj.t_end, 0.1)
    logged = traj.with_logs({"gnss": SensorLog(t[(t < traj.t_start + 12) | (t > traj.t_start + 20)])})
    inc = Incremental(rig)
    for c in chunks(logged, rig):
        inc.append(c)
    got, want = _sigma(inc.information().information, rig), sigmas(evaluate(logged, rig))
    assert got["gnss.trans_y"] == pytest.approx(want["gnss.trans_y"], rel=1e-7)
