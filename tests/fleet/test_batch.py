"""The CI gate: manifests (validated, errors naming the key), route collection, pass/fail semantics,
JUnit and JSON outputs, unreadable routes as per-route errors, and the bundled manifest passing."""

from __future__ import annotations

import json
import math
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from excite.fleet import batch as gate
from excite.cli.app import main
from excite.errors import ManifestError
from helpers import REPO

ROOT = REPO
TRAJ = ROOT / "trajectories"


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def junit_cases(path: Path) -> dict[str, ET.Element]:
    root = ET.parse(path).getroot()
    assert root.tag == "testsuites"
    return {c.get("name"): c for c in root.iter("testcase")}


@pytest.fixture
def routes(tmp_path: Path) -> Path:
    """A folder with copies of two reference routes."""
    for name in ("highway_run_control.csv", "figure_eight_control.csv"):
        shutil.copy(TRAJ / name, tmp_path / name)
    return tmp_path


def shortened(src: Path, dst: Path, keep_s: float) -> Path:
    """The control profile of ``src`` cut after ``keep_s`` seconds (someone shortened the loop)."""
    lines = src.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("t_s")]
    rows = [ln for ln in lines if ln and ln[0].isdigit() and float(ln.split(",")[0]) <= keep_s]
    dst.write_text("\n".join(head + rows) + "\n")
    return dst


# --- the bundled manifest -------------------------------------------------------------------


def test_bundled_manifest_passes_in_parallel(tmp_path: Path):
    junit = tmp_path / "out" / "junit.xml"
    assert main(["batch", str(TRAJ / "manifest.yaml"), "--junit", str(junit), "--jobs", "2"]) == 0
    cases = junit_cases(junit)
    expected = {p.name for p in TRAJ.iterdir() if p.suffix in (".tum", ".csv")}
    assert set(cases) == expected  # every reference file is gated, each once
    assert not any(c.find("failure") is not None or c.find("error") is not None for c in cases.values())


def test_bundled_manifest_expectations_are_resolved():
    specs = gate.load_manifest(TRAJ / "manifest.yaml")
    hw = next(s for s in specs if s.name == "highway_run_control.csv")
    bounds = {b.parameter: b for b in hw.determine}
    assert bounds["wheel.radius_left"].mode == bounds["wheel.radius_right"].mode == "target"
    assert bounds["imu.accel_bias_x"].sigma_max == pytest.approx(0.2)
    assert bounds["cam_front.rot_x"].sigma_max == pytest.approx(math.radians(0.07))
    f8 = {b.parameter: b for b in next(s for s in specs if s.name == "figure_eight.tum").determine}
    # a later, more specific key overrides the glob before it
    assert f8["lidar.rot_y"].mode == "target" and f8["lidar.rot_x"].sigma_max == pytest.approx(math.radians(0.1))
    assert f8["lidar.time_offset"].sigma_max == pytest.approx(2.5e-3)


# --- a route that rots fails, naming the parameter -----------------------------------------------


def test_route_that_lost_its_excitation_fails_naming_the_parameter(tmp_path: Path):
    shortened(TRAJ / "figure_eight_control.csv", tmp_path / "lot_loop.csv", keep_s=12.0)
    manifest = write(tmp_path / "manifest.yaml", """
routes:
  - route: lot_loop.csv
    determine:
      wheel.track: 1 cm
      wheel.radius_*: target
""")
    junit = tmp_path / "junit.xml"
    assert main(["batch", str(manifest), "--junit", str(junit), "--jobs", "1"]) == 1
    case = junit_cases(junit)["lot_loop.csv"]
    failure = case.find("failure")
    assert failure is not None and case.find("error") is None
    msg = failure.get("message")
    assert msg.startswith("wheel.track: ")  # the worst one first
    assert "> 1 cm (bound" in msg
    assert "Wheel track" in failure.text or "wheel" in failure.text.lower()  # the advice
    assert "what it takes:" in failure.text


def test_failure_message_gives_sigma_against_target_and_advice(routes: Path):
    manifest = write(routes / "m.yaml", """
rig: robotaxi
routes:
  - route: highway_run_control.csv
    name: highway
    min_score: 1.0e-6
    determine:
      wheel.track: target
      lidar.time_offset: 2 ms
      wheel.radius_left: target
      imu.accel_bias_y: observable
""")
    specs = gate.load_manifest(manifest)
    [res] = gate.run(specs, jobs=1)
    assert res.status == "failed"
    names = [f.parameter for f in res.failures]
    assert names[0] == "score"  # then the unobservable ones, then the rest by σ/bound
    assert set(names) == {"score", "wheel.track", "lidar.time_offset", "imu.accel_bias_y"}
    text = {f.parameter: f.text() for f in res.failures}
    assert text["wheel.track"] == "wheel.track: unobservable, must be ≤ 0.5 cm (target)"
    assert text["lidar.time_offset"].startswith("lidar.time_offset: σ ") and "> 2 ms (bound, " in text["lidar.time_offset"]
    assert text["imu.accel_bias_y"] == "imu.accel_bias_y: unobservable (must be observable)"
    assert any("Wheel track: turn both ways" in a for a in res.advice)
    xml = ET.fromstring(gate.junit_xml([res]))
    failure = xml.find(".//testcase/failure")
    assert "wheel.track: unobservable" in failure.get("message")
    assert "Wheel track: turn both ways" in failure.text


# --- pass/fail semantics without a manifest ----------------------------------------------------


def test_command_line_routes_default_to_every_parameter_within_target(routes: Path):
    [res] = gate.run(gate.collect([routes / "figure_eight_control.csv"]), jobs=1)
    assert res.status == "failed"  # a flat figure-eight leaves the vertical lever arms weak
    assert res.failures[0].parameter == "cam_front.trans_z"
    assert all(f.kind == "target" for f in res.failures)


def test_min_score_replaces_the_default_gate(routes: Path, tmp_path: Path):
    out = tmp_path / "r.json"
    f8 = str(routes / "figure_eight_control.csv")
    assert main(["batch", f8, "--min-score", "1e-4", "--json", str(out), "--jobs", "1"]) == 0
    doc = json.loads(out.read_text())
    assert doc["passed"] is True
    [r] = doc["routes"]
    assert r["status"] == "passed" and r["score"] == pytest.approx(r["report"]["score"])
    assert r["report"]["version"] == 2 and len(r["report"]["parameters"]) == 23
    assert main(["batch", f8, "--min-score", "1e-3", "--json", str(out), "--jobs", "1"]) == 1
    [r] = json.loads(out.read_text())["routes"]
    assert r["failures"][0]["parameter"] == "score" and r["failures"][0]["bound"] == 1e-3


def test_warnings_are_shown_and_kept_but_do_not_gate(tmp_path: Path, capsys):
    """A pose 500 m off: the table and the JSON carry the report's warning; the verdict is the
    score's alone (--min-score 0 passes it)."""
    rows = [r for r in (TRAJ / "figure_eight.tum").read_text().splitlines() if not r.startswith("#")]
    f = rows[400].split()
    f[1] = str(float(f[1]) + 500.0)
    rows[400] = " ".join(f)
    jump = write(tmp_path / "jump.tum", "\n".join(rows) + "\n")
    out = tmp_path / "r.json"
    assert main(["batch", str(jump), "--min-score", "0", "--json", str(out), "--jobs", "1"]) == 0
    shown = capsys.readouterr().out
    assert "warning:" in shown and "speed" in shown  # (a long path narrows the column: the words wrap)
    [r] = json.loads(out.read_text())["routes"]
    assert r["warnings"] and r["warnings"][0].startswith("speed ") and r["warnings"] == r["report"]["warnings"]


# --- errors: per route, never a traceback -----------------------------------------------------------


def test_unreadable_routes_are_errors_of_that_route(routes: Path, tmp_path: Path, capsys):
    bad = write(routes / "broken.csv", "t_s,speed_mps,curvature_1pm\n0,1,0\n0.1,abc,0\n")
    junit = tmp_path / "junit.xml"
    code = main(["batch", str(routes), str(tmp_path / "missing.tum"), "nothing*.csv", "--min-score", "0",
                 "--junit", str(junit), "--jobs", "1"])
    assert code == 1
    cases = junit_cases(junit)
    by_file = {Path(c.get("file")).name: c for c in cases.values()}
    assert by_file["highway_run_control.csv"].find("failure") is None  # score 0 ≥ 0: passes
    err = by_file["broken.csv"].find("error")
    assert err is not None and "broken.csv" in err.get("message") and "line 3" in err.get("message")
    assert "No such file" in by_file["missing.tum"].find("error").get("message")
    assert "no file matches" in by_file["nothing*.csv"].find("error").get("message")
    out = capsys.readouterr()
    assert "Traceback" not in out.out + out.err
    assert "2 passed, 0 failed, 3 errors" in out.out
    assert bad.exists()


def test_a_bug_while_evaluating_is_reported_with_its_traceback(routes: Path, monkeypatch):
    def boom(*args, **kwargs):
        raise RuntimeError("kaboom")

    monkeypatch.setattr(gate, "evaluate", boom)
    [res] = gate.run(gate.collect([routes / "highway_run_control.csv"]), jobs=1)
    assert res.status == "error" and res.error == "internal error: RuntimeError: kaboom"
    assert "Traceback" in res.error_detail
    assert "Traceback" in ET.fromstring(gate.junit_xml([res])).find(".//error").text


# --- manifest validation: every error names the key --------------------------------------------------


@pytest.mark.parametrize("body, message", [
    ("routes: []", "routes: expected a non-empty list"),
    ("rig: robotaxi", "routes: expected a non-empty list"),
    ("- a\n- b", "expected a mapping with a 'routes' list"),
    ("routs: []", "routs: unknown key"),
    ("version: 2\nroutes: [{route: a.csv}]", "version: only version 1"),
    ("routes: [{name: x}]", "routes.0.route: required"),
    ("routes: [{route: a.csv, min_scor: 1}]", "routes.0.min_scor: unknown key (known: route, name"),
    ("routes: [{route: a.csv, min_score: -1}]", "routes.0.min_score: expected a number ≥ 0"),
    ("routes: [{route: a.csv, min_score: yes}]", "routes.0.min_score: expected a number ≥ 0"),
    ("routes: [{route: a.csv, rig: nosuch}]", "routes.0.rig: no bundled rig named 'nosuch'"),
    ("rig: nosuch\nroutes: [{route: a.csv}]", "rig: no bundled rig named 'nosuch'"),
    ("routes: [{route: a.csv, determine: [wheel.track]}]", "routes.0.determine: expected a mapping"),
    ("routes: [{route: a.csv}, {route: b.csv, determine: {wheel.trak: target}}]",
     'routes.1.determine."wheel.trak": matches no parameter of rig robotaxi'),
    ("routes: [{route: a.csv, determine: {wheel.track: 1 deg}}]",
     'routes.0.determine."wheel.track": unit \'deg\' is not a unit of m'),
    ("routes: [{route: a.csv, determine: {wheel.track: -1 cm}}]", "must be positive"),
    ("routes: [{route: a.csv, determine: {'lidar.*': 1 cm}}]", "unit 'cm' is not a unit of rad"),
    ("routes: [{route: a.csv, times: 3}]", "routes.0.times: expected a path"),
    ("routes: [{route: a.csv\n", "line 2: not valid YAML"),
])
def test_manifest_errors_name_the_key(tmp_path: Path, body: str, message: str):
    path = write(tmp_path / "manifest.yaml", body)
    with pytest.raises(ManifestError) as err:
        gate.load_manifest(path)
    assert message in str(err.value)
    assert "manifest.yaml" in str(err.value)


def test_manifest_error_is_one_line_on_the_command_line(tmp_path: Path, capsys):
    path = write(tmp_path / "manifest.yaml", "routes: [{route: a.csv, determine: {wheel.trak: target}}]")
    assert main(["batch", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("excite: error: ") and 'routes.0.determine."wheel.trak"' in err
    assert len(err.strip().splitlines()) == 1


def test_bad_options_are_one_line_errors(routes: Path, capsys):
    assert main(["batch", str(routes), "--rig", "nosuch"]) == 1
    assert "--rig: no bundled rig named 'nosuch'" in capsys.readouterr().err
    assert main(["batch", str(routes), "--min-score", "-1"]) == 1
    assert "--min-score must be a number ≥ 0" in capsys.readouterr().err
    assert main(["batch", str(routes), "--jobs", "0"]) == 1
    assert "--jobs must be ≥ 1" in capsys.readouterr().err


# --- collecting routes ----------------------------------------------------------------------------------


def test_folders_hold_route_files_only_and_kitti_pairs_with_its_times(tmp_path: Path):
    for name in ("a.csv", "b.tum", "c.geojson", "README.md", "readme.txt", "manifest.yaml",
                 "seq_poses.txt", "seq_times.txt", "notes.pdf"):
        write(tmp_path / name, "x")
    (tmp_path / "sub").mkdir()
    specs = gate.collect([tmp_path])
    assert [Path(s.path).name for s in specs] == ["a.csv", "b.tum", "c.geojson", "seq_poses.txt"]
    kitti = specs[-1]
    assert kitti.times == str(tmp_path / "seq_times.txt")
    assert all(s.source == gate.COMMAND_LINE and s.default_gate for s in specs)
    assert [Path(s.path).name for s in gate.collect([str(tmp_path / "*.tum")])] == ["b.tum"]


def test_manifest_paths_are_relative_to_the_manifest_and_globs_expand(routes: Path):
    sub = routes / "m"
    sub.mkdir()
    manifest = write(sub / "routes.yml", """
routes:
  - route: ../*_control.csv
    name: lot
    min_score: 0
  - route: missing.csv
""")
    specs = gate.collect([manifest])
    assert [s.name for s in specs] == ["lot/figure_eight_control.csv", "lot/highway_run_control.csv", "missing.csv"]
    assert Path(specs[0].path).resolve() == (routes / "figure_eight_control.csv").resolve()
    assert specs[0].min_score == 0 and specs[2].default_gate
    assert all(s.source.endswith("routes.yml") for s in specs)


def test_kitti_times_from_the_manifest(tmp_path: Path, data_dir: Path):
    manifest = write(tmp_path / "kitti.yaml", f"""
routes:
  - route: {data_dir / 'kitti_00_poses.txt'}
    times: {data_dir / 'kitti_00_times.txt'}
    name: kitti_00
    min_score: 1.0e-3
    determine:
      wheel.track: 1 cm
      lidar.time_offset: 2 ms
""")
    [res] = gate.run(gate.collect([manifest]), jobs=1)
    assert res.status == "passed", res.failures or res.error
    assert res.score == pytest.approx(0.0032, rel=0.2)
