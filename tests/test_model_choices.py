"""Issue 11: the numbers must not move with arbitrary choices — the keyframe rate (a
discretisation), the accuracy targets (they scale σ/target, never what is observable), and one
drive's nuisances must not leak into another's."""

from __future__ import annotations

import math

import pytest

from excite.errors import RigError
from excite.evaluate import evaluate
from excite.rig import build_rig, load_rig
from excite.routes import read_route


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


def _sigmas(traj, rig):
    rep = evaluate(traj, rig)
    return {p.name: p.sigma for p in rep.parameters}


def _assert_rate_converged(traj, rig):
    """σ of every parameter changes by < 3 % from 10 to 20 Hz keyframes and from 20 to 40 Hz."""
    s10, s20, s40 = (_sigmas(traj, rig.with_config(keyframe_rate_hz=kf)) for kf in (10, 20, 40))
    for name in s10:
        assert s10[name] is not None and s20[name] is not None and s40[name] is not None, name
        assert s20[name] / s10[name] == pytest.approx(1.0, abs=0.03), (name, s10[name], s20[name])
        assert s40[name] / s20[name] == pytest.approx(1.0, abs=0.03), (name, s20[name], s40[name])


@pytest.mark.parametrize("route", ["figure_eight_control.csv", "slalom_control.csv"])
def test_sigma_converges_as_the_keyframe_rate_grows(rig, route):
    _assert_rate_converged(read_route(f"trajectories/{route}", suspension=rig.suspension), rig)


def test_sigma_converges_as_the_keyframe_rate_grows_on_kitti(rig, data_dir):
    traj = read_route(data_dir / "kitti_00_poses.txt", times=data_dir / "kitti_00_times.txt",
                      suspension=rig.suspension)
    _assert_rate_converged(traj, rig)


def test_wheel_and_slip_noise_are_densities(rig):
    """Per keyframe σ = density·√Δt for a wheel increment and density·√rate for the sampled slip
    velocity: their information per second is the same at every keyframe rate."""
    for kf in (10, 20, 40):
        r = rig.with_config(keyframe_rate_hz=kf)
        assert r.wheel_increment_sigma_rad ** 2 * kf == pytest.approx(rig.config.wheels.noise_density ** 2)
        lat, vert = r.nonholonomic_sigma_mps
        nh = rig.config.vehicle.nonholonomic
        assert lat ** 2 / kf == pytest.approx(nh.lateral_noise_density ** 2)
        assert vert ** 2 / kf == pytest.approx(nh.vertical_noise_density ** 2)


@pytest.mark.parametrize("where, old, new, factor", [
    (("wheels",), "sigma_rad", "noise_density", math.sqrt(10.0)),
    (("vehicle", "nonholonomic"), "lateral_sigma_mps", "lateral_noise_density", 1 / math.sqrt(10.0)),
    (("vehicle", "nonholonomic"), "vertical_sigma_mps", "vertical_noise_density", 1 / math.sqrt(10.0)),
])
def test_per_keyframe_noise_keys_get_a_migration_error(rig, where, old, new, factor):
    data = rig.config.model_dump()
    node = data
    for k in where:
        node = node[k]
    node.pop(new)
    node[old] = 0.02
    with pytest.raises(RigError) as err:
        build_rig(data)
    msg = str(err.value)
    assert msg.startswith(".".join(where) + "." + old), msg
    assert f"{new}: {0.02 * factor:.4g}" in msg, msg
