"""small_gicp registrations in the tunnel: nothing along its axis (the simulator and what it
states: tests/scan_registration.py)."""

from __future__ import annotations

import numpy as np
import pytest

from excite.scene.files import load_scene

pytest.importorskip("small_gicp")
from scan_registration import PRIOR, monte_carlo, yaw  # noqa: E402

pytestmark = [pytest.mark.montecarlo, pytest.mark.slow]


def test_the_tunnel_tells_nothing_along_its_axis():
    """Three places across the tunnel, 0.4 and 0.8 m per pair."""
    scene = load_scene("tunnel")
    starts = [(yaw(0.0), np.array([700.0 + 50 * k, y, 1.9])) for k, y in enumerate((-2.0, 0.0, 2.0))]
    along, across = [], []
    for speed in (4.0, 8.0):
        # (along the axis small_gicp never stops: each iteration slides on)
        for r in monte_carlo(scene, starts, 4, seed=int(speed), speed=speed, yaw_rate=0.0, converged=False):
            # the scan looks along the axis: the axis's row of H is exactly zero
            assert np.array_equal(r["H"][3], np.zeros(6)) and np.array_equal(r["H"][:, 3], np.zeros(6))
            along.append(r["err"][:, 3])
            across.append(r["err"][:, [0, 1, 2, 4, 5]] / r["sigma"][[0, 1, 2, 4, 5]])
    along, across = np.concatenate(along), np.concatenate(across)
    rms = np.sqrt((across**2).mean(axis=0))
    print(f"\ntunnel: along the axis, errors of {along.std() * 1e2:.1f} cm spread (the initial guess's 3 cm); "
          f"across it, errors of {np.round(rms, 2)} of the model's σ (rms per axis)")
    # along the axis the registration ends wherever the map's sampling lets it slide: no closer to
    # the truth than the guess it started from (across the axis it is millimetres)
    assert along.std() > PRIOR[3]
    # across it, registered to about the model's σ (the slide along the axis drags roll and the
    # lateral translation with it)
    assert np.all(rms < 2.5), rms
