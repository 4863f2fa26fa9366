"""Hostile input to the library and the CLI: tiny files whose work explodes, absurd but finite
numbers, pathological structure. Each is refused before any large allocation with one error
that names the field (file and line) and quotes the bound; the CLI prints it as one line, also
under an address-space limit that a single unbounded allocation would exceed."""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from excite.core import bounds
from excite.io import poses, routes
from excite.errors import BagError, EvaluationError, LimitError, OptimizeError, RigError, RouteError
from excite.score.evaluate import Options, evaluate
from excite.plan import OptimizeSettings
from excite.factors import base as registry
from excite.rig.config import RigConfig, build_rig, load_rig, rig_range
from excite.motion.trajectory import Trajectory
from excite.motion.vehicle import ControlProfile, Limits
from helpers import REPO



# --------------------------------------------------------------------------------------------
# Every numeric rig key has a range, and values outside it are refused naming key and range


def _numeric_keys(schema: dict, node: dict, prefix: str = "") -> list[str]:
    """Dotted keys (list items as 0) of every number in a JSON schema."""
    if "$ref" in node:
        node = schema["$defs"][node["$ref"].split("/")[-1]]
    if "anyOf" in node:
        return sorted({k for n in node["anyOf"] for k in _numeric_keys(schema, n, prefix)})
    kind = node.get("type")
    if "enum" in node or "const" in node:
        return []  # a choice of values (a Literal) is its own range
    if kind in ("number", "integer"):
        return [prefix.rstrip(".")]
    if kind == "object":
        return [k for name, sub in node.get("properties", {}).items()
                for k in _numeric_keys(schema, sub, f"{prefix}{name}.")]
    if kind == "array":
        items = node.get("prefixItems") or [node.get("items", {})]
        return sorted({k for sub in items for k in _numeric_keys(schema, sub, f"{prefix}0.")})
    return []


def test_every_numeric_rig_key_has_a_sane_range():
    """Every number of a rig file has a range: the rig's own keys, and every registered kind's
    (a sensor entry's, a section's)."""
    schema = RigConfig.model_json_schema()
    cfg = load_rig("robotaxi").config
    keys = [k for k in _numeric_keys(schema, schema) if not k.startswith(("targets", "priors"))]
    missing = [k for k in keys if rig_range(cfg, k) is None]
    n = len(keys)
    for kind in registry.kinds():
        if kind.config is not None and (kind.sensor_kinds or kind.section):
            sub = kind.config.model_json_schema()
            prefix = f"sensors.0({kind.name})." if kind.sensor_kinds else f"{kind.section}."
            own = _numeric_keys(sub, sub)
            n += len(own)
            # a sensor kind's keys are its own ranges' (an entry of any kind may be sensors.0)
            common = "sensors.0." if kind.sensor_kinds else f"{kind.section}."
            missing += [prefix + k for k in own if k not in kind.ranges and bounds.rig_range(common + k) is None]
    assert n > 40
    assert not missing, f"add ranges for these rig keys (excite.core.bounds.RIG, or the kind's ranges): {missing}"


def _robotaxi() -> dict:
    return json.loads(json.dumps(load_rig("robotaxi").config.model_dump()))


def _set(data: dict, key: str, value: float) -> dict:
    out = copy.deepcopy(data)
    *parents, last = key.split(".")
    node = out
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node[p]
    node[int(last) if isinstance(node, list) else last] = value
    return out


def _rig_cases():
    data = _robotaxi()
    for key, x in bounds.rig_numbers(data):
        r = rig_range(load_rig("robotaxi").config, key)
        for bad in (r.hi * 10 + 1, r.lo - 10 * max(abs(r.lo), 1e-300) - 1e-300, 1e300, -1e300):
            if not r.contains(bad):
                yield key, bad


@pytest.mark.parametrize("key,value", list(_rig_cases()))
def test_absurd_rig_numbers_are_refused_naming_key_and_range(key, value):
    r = rig_range(load_rig("robotaxi").config, key)
    with pytest.raises(RigError) as exc:
        build_rig(_set(_robotaxi(), key, value))
    msg = str(exc.value)
    # a matrix entry fails the rotation check of its pose first; a negative density, "> 0"
    assert msg.startswith(key.split(".matrix")[0]), msg
    if value > r.hi and ".matrix" not in key:
        assert f"outside the sane range {r}" in msg, msg


@pytest.mark.parametrize("target", ["1e308 deg", 1e308, "1e-308 mrad", 1e-300])
def test_absurd_targets_and_priors_are_refused(target):
    data = _robotaxi()
    data["targets"] = dict(data["targets"], **{"*.rot_*": target})
    with pytest.raises(RigError, match=r"targets\.\*\.rot_\*: .* outside the sane range"):
        build_rig(data)
    data = _robotaxi()
    data["priors"] = {"*.rot_*": target}
    with pytest.raises(RigError, match=r"priors\.\*\.rot_\*: .* outside the sane range"):
        build_rig(data)


def test_rig_structure_is_bounded():
    data = _robotaxi()
    sensor = data["sensors"][0]
    data["sensors"] = [dict(sensor, name=f"s{i}") for i in range(500)]
    with pytest.raises(RigError, match=f"500 sensors, over the limit of {bounds.MAX_SENSORS}"):
        build_rig(data)
    data = _robotaxi()
    data["targets"] = {f"*.r{i}*": "1 deg" for i in range(bounds.MAX_RIG_NODES)}
    with pytest.raises(RigError, match=f"rig: more than {bounds.MAX_RIG_NODES} keys and list items"):
        build_rig(data)
    deep: dict = {}
    node = deep
    for _ in range(950):
        node["a"] = {}
        node = node["a"]
    with pytest.raises(RigError, match="nested more than"):
        build_rig({"imu": deep})


def test_deep_rig_yaml_is_an_error_not_a_crash(tmp_path):
    path = tmp_path / "deep.yaml"
    path.write_text("imu: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(RigError):
        load_rig(path)


# --------------------------------------------------------------------------------------------
# Routes, limits, options: absurd numbers


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _tum_with(row: int, fields: str) -> str:
    lines = [f"{i / 10} {i} 0 0 0 0 0 1" for i in range(10)]
    lines[row] = fields
    return "\n".join(lines) + "\n"


ROUTE_NUMBERS = [
    ("coords.tum", _tum_with(5, "0.5 1e300 0 0 0 0 0 1"), 6, "position"),
    ("time.tum", _tum_with(9, "1e300 9 0 0 0 0 0 1"), 10, "time"),
    ("ctl_speed.csv", "t_s,speed_mps,curvature_1pm\n0,0,0\n5,1e308,0\n10,0,0\n", 3, "speed_mps"),
    ("ctl_curv.csv", "t_s,speed_mps,curvature_1pm\n0,0,0\n5,5,1e300\n10,0,0\n", 3, "curvature_1pm"),
    ("ctl_grade.csv", "t_s,speed_mps,curvature_1pm,grade_rad\n0,0,0,0\n5,5,0,-1e300\n10,0,0,0\n", 3, "grade_rad"),
    ("ctl_start.csv", "# start: x_m=1e300 y_m=0 heading_rad=0\nt_s,speed_mps,curvature_1pm\n0,0,0\n5,5,0\n10,0,0\n",
     1, "start x_m"),
    ("wp.csv", "x,y\n0,0\n1e300,0\n", 3, "coordinate"),
    ("wp_speed.csv", "x,y,z,speed\n0,0,0,1\n10,0,0,1e308\n", 3, "speed"),
    ("wp_alt.csv", "x,y,z\n0,0,0\n10,0,1e300\n", 3, "altitude"),
]


@pytest.mark.parametrize("name,text,line,what", ROUTE_NUMBERS, ids=[c[0] for c in ROUTE_NUMBERS])
def test_absurd_route_numbers_are_refused_naming_line_and_range(tmp_path, name, text, line, what):
    path = _write(tmp_path, name, text)
    with pytest.raises(RouteError) as exc:
        routes.read_route(path)
    assert exc.value.source == str(path) and exc.value.line == line, str(exc.value)
    assert what in exc.value.problem and "sane range [" in exc.value.problem


def test_absurd_geojson_altitude(tmp_path):
    path = _write(tmp_path, "alt.geojson", '{"type": "LineString", "coordinates": '
                  '[[11.0, 48.0, 0], [11.001, 48.0, 1e300]]}')
    with pytest.raises(RouteError, match=r"altitude 1e\+300 is outside the sane range"):
        routes.read_route(path)


@pytest.mark.parametrize("name", list(bounds.LIMITS))
@pytest.mark.parametrize("value", [1e308, 1e-308, -1.0, math.nan])
def test_absurd_limits(name, value):
    with pytest.raises(LimitError, match=f"limits.{name}: .*sane range {re_escape(str(bounds.LIMITS[name]))}"):
        Limits(**{name: value})


def re_escape(text: str) -> str:
    import re

    return re.escape(text)


@pytest.mark.parametrize("kw", [{"segments": 10**9}, {"weak_below": 1e308}, {"weak_below": 1e-308},
                                {"max_modes": 0}])
def test_absurd_options(kw):
    with pytest.raises(EvaluationError, match="outside the sane range"):
        Options(**kw)


@pytest.mark.parametrize("kw", [{"duration_s": 1e308}, {"lot_x_m": 1e300}, {"time_budget_s": 1e-300},
                                {"n_random": 10**12}, {"seed": 2**40}])
def test_absurd_optimizer_settings(kw):
    with pytest.raises(OptimizeError, match="outside the sane range"):
        OptimizeSettings(**kw)


# --------------------------------------------------------------------------------------------
# Tiny inputs whose work explodes: refused before allocating, quoting the bound


def _tum(times: np.ndarray) -> str:
    return "".join(f"{float(t)!r} {1e-6 * float(t)!r} 0 0 0 0 0 1\n" for t in times)


EXPLOSIONS = [
    # 3 knots over 10⁶ s: 10⁸ samples of the 100 Hz drive grid
    ("span.csv", "t_s,speed_mps,curvature_1pm\n0,0,0\n500000,5,0.1\n1000000,0,0\n", "14400 s"),
    # 10 poses over 9·10⁷ s
    ("sparse.tum", _tum(np.linspace(0.0, 9e7, 10)), "14400 s"),
    # a legal duration, but the median pose spacing is a microsecond: 10¹⁰ resampled samples
    ("dense.tum", _tum(np.r_[np.arange(8) * 1e-6, 10_000.0, 10_001.0]), "2,000,000"),
    # epoch-like times that span far too long
    ("epoch.tum", _tum(1.7e9 + np.linspace(0.0, 1e6, 10)), "14400 s"),
    # two waypoints 5000 km apart: a path resampled every few cm
    ("far.csv", "x,y\n0,0\n5000000,0\n", "200000 m"),
    # a creeping speed: a 20 km path at 1 mm/s takes 2·10⁷ s
    ("creep.csv", "x,y,z,speed\n0,0,0,0.001\n20000,0,0,0.001\n", "14400 s"),
]


@pytest.mark.parametrize("name,text,bound", EXPLOSIONS, ids=[c[0] for c in EXPLOSIONS])
def test_tiny_files_with_explosive_work_are_refused_quoting_the_bound(tmp_path, name, text, bound):
    path = _write(tmp_path, name, text)
    with pytest.raises(RouteError) as exc:
        routes.read_route(path)
    assert bound in str(exc.value) and "limit" in str(exc.value)


def test_library_entry_points_bound_the_work():
    with pytest.raises(RouteError, match="14400 s"):
        ControlProfile(t_s=[0.0, 1e6], speed_mps=[0.0, 0.0], curvature_1pm=[0.0, 0.0])
    with pytest.raises(RouteError, match="14400 s"):
        poses.trajectory_from_poses(np.linspace(0, 9e7, 10), np.zeros((10, 3)),
                                     np.broadcast_to(np.eye(3), (10, 3, 3)))
    with pytest.raises(RouteError, match="200000 m"):
        routes.route_from_waypoints(np.array([[0.0, 0.0], [1e7, 0.0]]))
    # within the duration bound, but 2 h at a 100 Hz keyframe rate are 720 000 keyframes
    rig = load_rig("robotaxi").with_config(keyframe_rate_hz=100.0, sensors=[], imu=dict(
        load_rig("robotaxi").config.imu.model_dump(), update_rate=1000.0), targets={
        "imu.*": 1.0, "wheel.*": 0.01})
    t = np.linspace(0.0, 7200.0, 50)
    traj = Trajectory(t, np.broadcast_to(np.eye(3), (50, 3, 3)), np.c_[t, np.zeros((50, 2))])
    with pytest.raises(EvaluationError, match="keyframes, over the limit of 200,000"):
        evaluate(traj, rig)


# --------------------------------------------------------------------------------------------
# The CLI: one line, and bounded memory


DRIVER = """
import contextlib, io, json, resource, sys
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from excite.cli.app import main
out = []
for path in sys.argv[2:]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(["score", path])
        except BaseException as exc:  # a traceback: reported, not raised
            rc, err = -1, io.StringIO(repr(exc))
    out.append([rc, err.getvalue()])
print(json.dumps(out))
"""


def test_cli_hostile_inputs_end_in_one_line_within_bounded_memory(tmp_path):
    """Under a 1 GiB address-space limit (a normal `excite score` fits in it): before the
    bounds, the first file made `excite score` grow to 24 GB."""
    files = [_write(tmp_path, name, text) for name, text, _ in EXPLOSIONS[:4]]
    files.append(_write(tmp_path, "coords.tum", ROUTE_NUMBERS[0][1]))
    files.append(REPO / "trajectories" / "figure_eight_control.csv")  # and a normal one works
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", DRIVER, str(2**30), *map(str, files)], cwd=tmp_path,
                       env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    results = json.loads(r.stdout.strip().splitlines()[-1])
    *hostile, normal = zip(files, results)
    for path, (rc, err) in hostile:
        lines = err.strip().splitlines()
        assert rc == 1 and len(lines) == 1, (path.name, err[-2000:])
        assert lines[0].startswith(f"excite: error: {path}"), lines[0]
        assert "limit" in lines[0] or "sane range" in lines[0], lines[0]
    assert normal[1][0] == 0, normal[1][1]


def test_cli_edges_are_one_line_errors(tmp_path, capsys):
    from excite.cli.app import main

    existing = _write(tmp_path, "existing.txt", "x")
    (tmp_path / "folder.csv").mkdir()
    route = str(REPO / "trajectories" / "figure_eight_control.csv")
    cases = [
        (["optimize", "-o", str(existing)], "exists and is not a folder"),
        (["optimize", "-o", str(tmp_path / "o"), "--duration", "1e308"], "duration_s: 1e+308 is outside"),
        (["score", str(tmp_path / "folder.csv")], "folder.csv: Is a directory"),
        (["score", route, "--segments", "1000000"], "segments: 1000000 is outside"),
        (["score", route, "--rig", str(_write(tmp_path, "deep.yaml", "imu: " + "[" * 3000 + "]" * 3000))],
         "deep.yaml: nested more than"),
        (["rig", "show", str(_write(tmp_path, "big.yaml", "imu: {update_rate: 1e308}"))], "big.yaml"),
        (["serve", "--log-level", "loud"],
         "--log-level: 'loud' is not one of critical, error, warning, info, debug, trace"),
    ]
    for args, words in cases:
        capsys.readouterr()
        rc = main(args)
        lines = capsys.readouterr().err.strip().splitlines()
        assert rc == 1 and len(lines) == 1 and lines[0].startswith("excite: error:"), (args, lines)
        assert words in lines[0], lines[0]


def test_a_service_can_tighten_the_bounds_and_they_are_quoted(tmp_path):
    path = _write(tmp_path, "creep.csv", "x,y,z,speed\n0,0,0,0.5\n300,0,0,0.5\n")  # 600 s
    assert routes.read_route(path).duration > 500
    with bounds.tightened(duration_s=120.0):
        with pytest.raises(RouteError, match="over the limit of 120 s"):
            routes.read_route(path)
        with bounds.tightened(duration_s=1e9):  # never loosened
            assert bounds.max_duration_s() == 120.0
    assert bounds.max_duration_s() == bounds.MAX_DURATION_S


def test_deeply_nested_geojson_is_an_error_not_a_crash(tmp_path):
    path = _write(tmp_path, "deep.geojson", "[" * 100_000 + "]" * 100_000)
    with pytest.raises(RouteError, match="nested too deeply"):
        routes.read_route(path)


def test_deeply_nested_manifest_is_an_error_not_a_crash(tmp_path):
    from excite.errors import ManifestError
    from excite.fleet.batch import collect

    path = _write(tmp_path, "routes.yaml", "routes: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ManifestError, match="nested too deeply"):
        collect([str(path)])


# --------------------------------------------------------------------------------------------
# Bags: the same work bounds, from the bag's index and its stamps, before anything is built


def _pose_bag(path: Path, times_s: list[float]) -> Path:
    """A ROS 1 bag with one PoseStamped per time on /pose (a straight line, 1 m per message)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    M = ts.types
    with Writer(path) as w:
        c = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for i, t in enumerate(times_s):
            ns = 1_700_000_000 * 10**9 + int(round(t * 1e9))
            stamp = M["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            msg = M["geometry_msgs/msg/PoseStamped"](
                header=M["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="odom"),
                pose=M["geometry_msgs/msg/Pose"](
                    position=M["geometry_msgs/msg/Point"](x=float(i), y=0.0, z=0.0),
                    orientation=M["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
            w.write(c, ns, ts.serialize_ros1(msg, "geometry_msgs/msg/PoseStamped"))
    return path


BAG_EXPLOSIONS = [
    # seven poses a second apart, then one 10⁶ s later: a 10⁶ s drive
    ("far.bag", [0, 1, 2, 3, 4, 5, 6, 1e6], "over the limit of 14400 s"),
    # a legal hour, but poses a microsecond apart: 3.6·10⁹ samples at the median rate
    ("dense.bag", [0, 1e-6, 2e-6, 3e-6, 4e-6, 5e-6, 6e-6, 3600], "over the limit of 2,000,000"),
]


@pytest.mark.parametrize("name,times,bound", BAG_EXPLOSIONS, ids=[c[0] for c in BAG_EXPLOSIONS])
def test_bags_whose_stamps_imply_explosive_work_are_refused_quoting_the_bound(tmp_path, capsys, name,
                                                                              times, bound):
    from excite.errors import BagError
    from excite.io.bags import read_bag_route
    from excite.cli.app import main

    path = _pose_bag(tmp_path / name, times)
    with pytest.raises(BagError) as exc:
        read_bag_route(path, "/pose")
    assert bound in str(exc.value) and str(path) in str(exc.value) and "/pose" in str(exc.value)
    capsys.readouterr()
    assert main(["score", str(path), "--topic", "/pose"]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"excite: error: {path}") and bound in lines[0], lines


def test_a_bag_topic_with_more_messages_than_the_bounds_is_refused_before_reading(tmp_path, monkeypatch):
    """The count comes from the bag's index: no message is decoded (nor memory taken) first."""
    from excite.io import bags

    path = _pose_bag(tmp_path / "many.bag", [0.1 * i for i in range(12)])
    assert bags.read_bag_route(path, "/pose").duration == pytest.approx(1.1)
    monkeypatch.setattr(bounds, "MAX_SAMPLES", 10)

    def decoded(*_a, **_k):
        raise AssertionError("a message was decoded before the count was checked")

    monkeypatch.setattr(bags.Series, "add", decoded)
    monkeypatch.setattr(bags.Series, "add_many", decoded)
    with pytest.raises(BagError, match=r"topic /pose: 12 messages, over the limit of 10 poses"):
        bags.read_bag_route(path, "/pose")


def test_a_compressed_mcap_chunk_cannot_expand_past_what_it_declares():
    """A chunk of zeros compresses ~1000:1; it is decompressed only up to its declared size
    (itself bounded), so a small file cannot claim all of memory."""
    from excite.io import bags

    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    from lz4.frame import compress as lz4

    zeros = bytes(50_000_000)
    for kind, blob in (("zstd", zstd.compress(zeros)), ("lz4", lz4(zeros))):
        assert len(blob) < 1_000_000
        assert bags.decompress(kind, blob, len(zeros)) == zeros
        with pytest.raises(ValueError, match="declares 1,000 bytes but holds 1,001 or more"):
            bags.decompress(kind, blob, 1000)
    with pytest.raises(ValueError, match="over the limit"):
        bags.decompress("zstd", zstd.compress(b"x"), bags.MAX_CHUNK_BYTES + 1)
