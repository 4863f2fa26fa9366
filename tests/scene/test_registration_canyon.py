"""Monte Carlo of small_gicp registrations in the street canyon: the NEES against excite's
information inside its interval (the simulator and what it states: tests/scan_registration.py)."""

from __future__ import annotations

import numpy as np
import pytest

from excite.scene.files import load_scene

pytest.importorskip("small_gicp")
from scan_registration import DRAWS, monte_carlo, report, yaw  # noqa: E402

pytestmark = [pytest.mark.montecarlo, pytest.mark.slow]


def test_excite_sigma_against_small_gicp_registrations_in_the_street_canyon():
    starts = [(yaw(0.0), np.array([x, y, 1.9])) for x, y in ((-60.0, 8.0), (-10.0, -6.0), (30.0, 3.0), (70.0, -12.0))]
    runs = monte_carlo(load_scene("street_canyon"), starts, DRAWS, seed=1)
    m, n, (lo, hi), spread, bias = report("street_canyon", runs)
    assert n >= 200 and all(np.isfinite(r["sigma"]).all() for r in runs)
    assert lo < m < hi
    assert np.all((spread > 0.65) & (spread < 1.35)), spread
    # no pose biased along any axis beyond what 50 draws' means scatter (σ/√50 ≈ 0.14 σ each)
    assert np.abs(bias).max() < 0.75, bias
