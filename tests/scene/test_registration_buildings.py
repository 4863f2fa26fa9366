"""Monte Carlo of small_gicp registrations in the lot with buildings on one side: the NEES against
excite's information inside its interval (the simulator and what it states: tests/scan_registration.py)."""

from __future__ import annotations

import numpy as np
import pytest

from excite.scene.files import load_scene

pytest.importorskip("small_gicp")
from scan_registration import DRAWS, monte_carlo, report, yaw  # noqa: E402

pytestmark = [pytest.mark.montecarlo, pytest.mark.slow]


def test_excite_sigma_against_small_gicp_registrations_in_the_lot_with_buildings():
    starts = [(yaw(a), np.array([x, y, 1.9])) for a, x, y in (
        (0.0, -20.0, 10.0), (np.pi / 2, 0.0, 0.0), (np.pi, 20.0, -10.0), (-np.pi / 2, 10.0, 15.0))]
    runs = monte_carlo(load_scene("lot_buildings_one_side"), starts, DRAWS, seed=1)
    m, n, (lo, hi), spread, bias = report("lot_buildings_one_side", runs)
    assert n >= 200 and all(np.isfinite(r["sigma"]).all() for r in runs)  # every direction is seen
    assert lo < m < hi
    # and along every axis, not only on the whole: a spread of 50 draws within its sampling error
    # (a tenth)
    assert np.all((spread > 0.65) & (spread < 1.35)), spread
    assert np.abs(bias).max() < 0.75, bias
