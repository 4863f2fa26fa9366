"""The comma2k19 minute scored with its u-blox GNSS (issue 27): examples/comma2k19_gnss.yaml on
the recording read by the comma2k19 reader (``excite.io.comma2k19``, the car kinds')."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excite.motion.trajectory import SensorLog
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def minute(data_dir):
    from excite.io import comma2k19 as comma

    rec = comma.read_comma2k19(data_dir / "comma2k19_rav4_seg40")
    return rec, comma.trajectory(rec)


def _with_fixes(rec, traj):
    fixes = rec.gnss["ublox"]
    t = np.asarray(fixes.fix_t, dtype=float)  # the fix epochs on the drive's clock
    return traj.with_logs({"gnss": SensorLog(np.unique(t))})


def test_the_minute_scored_with_its_gnss(minute):
    """An almost straight minute (heading within 1.2°, the body pitching a few tenths of a degree
    under braking), its 19 missing u-blox fixes outages from the log: the fix's time offset is
    determined to a few centimetres' worth (speed 8–20 m/s: tens of ms), the lever arm only to
    metres, horizontally weakest (the constant-heading row of the table, weak rather than exact
    on a real car)."""
    rec, traj = minute
    logged = _with_fixes(rec, traj)
    rig = load_rig(EXAMPLES / "comma2k19_gnss.yaml")
    from excite.factors.base import Nominal

    nom = Nominal.of(logged, rig)
    held = int(nom.logs["gnss"].available.sum())
    assert 560 <= held <= 598  # the fixes the log holds on the keyframes (579 in the minute)
    rep = evaluate(logged, rig)
    s = {p.name: p.sigma for p in rep.parameters}
    assert s["gnss.time_offset"] < 0.1
    assert all(s[f"gnss.trans_{a}"] is None or s[f"gnss.trans_{a}"] > 0.5 for a in "xyz")
    weakest = rep.weak_modes[0]
    assert weakest.coordinates[0][0] in ("gnss.trans_x", "gnss.trans_y") and "heading" in weakest.advice
    full = {p.name: p.sigma for p in evaluate(traj, rig).parameters}
    assert s["gnss.time_offset"] >= full["gnss.time_offset"] * (1 - 1e-9)  # the outages cost, never help
