"""`excite score` and `excite rig show` with a car rig (four CAN wheel speeds, the steering angle,
a radar): the command line needs no change for the new kinds."""

from __future__ import annotations

import json
import numpy as np
import pytest
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig


@pytest.fixture(scope="module")
def rig():
    return load_rig("sedan")


def test_the_command_line_scores_and_shows_the_rig(tmp_path, capsys):
    from excite.cli.app import main
    from excite.io.routes import write_tum

    t = np.linspace(0.0, 30.0, 61)
    route = write_tum(drive(ControlProfile(t, 5 + 2 * np.sin(t / 3), 0.1 * np.sin(t / 4))), tmp_path / "drive.tum")
    assert main(["score", str(route), "--rig", "sedan", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    names = {p["name"] for p in out["parameters"]}
    assert {"wheel.wheelbase", "steering.ratio", "radar_front.rot_z"} <= names
    assert main(["rig", "show", "sedan"]) == 0 and "ackermann:" in capsys.readouterr().out
