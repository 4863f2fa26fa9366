"""Routes and logs by URL (excite.io.remote): a loopback HTTP server started here serves copies of
real files; what `excite batch` and `excite mine` make of a URL equals what they make of the
same bytes on disk, and a URL that cannot be read is that route's error, named."""

from __future__ import annotations

import functools
import http.server
import json
import shutil
import threading
from pathlib import Path

import pytest

from excite.fleet import batch as gate
from excite.fleet import mine
from excite.io import remote
from excite.cli.app import main
from excite.errors import RouteError
from helpers import REPO

ROOT = REPO
FIGURE_EIGHT = ROOT / "trajectories" / "figure_eight.tum"
FIGURE_EIGHT_CONTROL = ROOT / "trajectories" / "figure_eight_control.csv"


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # keep pytest's output clean
        pass


@pytest.fixture(scope="module")
def served(tmp_path_factory, data_dir):
    """(base URL, folder) of an HTTP server on loopback serving a folder of route files."""
    d = tmp_path_factory.mktemp("served")
    for f in (FIGURE_EIGHT, FIGURE_EIGHT_CONTROL, data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt"):
        shutil.copy(f, d / f.name)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(d)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}", d
    server.shutdown()
    server.server_close()


def test_batch_of_a_url_equals_the_file(served, tmp_path, capsys):
    base, d = served
    out_url, out_file = tmp_path / "url.json", tmp_path / "file.json"
    assert main(["batch", f"{base}/figure_eight.tum", "--min-score", "0", "--json", str(out_url)]) == 0
    assert main(["batch", str(d / "figure_eight.tum"), "--min-score", "0", "--json", str(out_file)]) == 0
    url, local = (json.loads(p.read_text())["routes"][0] for p in (out_url, out_file))
    assert url["name"] == url["path"] == f"{base}/figure_eight.tum"
    assert url["score"] == local["score"] > 0
    assert url["report"]["parameters"] == local["report"]["parameters"]


def test_a_manifest_names_urls_for_route_and_times(served, tmp_path, data_dir):
    """KITTI poses and times both by URL, next to a local route: the same report as on disk."""
    base, d = served
    manifest = tmp_path / "routes.yaml"
    manifest.write_text(f"""\
rig: robotaxi
routes:
  - route: {base}/kitti_00_poses.txt
    times: {base}/kitti_00_times.txt
    name: kitti-by-url
    min_score: 0
  - route: {data_dir / 'kitti_00_poses.txt'}
    name: kitti-on-disk
    min_score: 0
""")
    specs = gate.collect([manifest])
    assert specs[0].path == f"{base}/kitti_00_poses.txt" and specs[0].times == f"{base}/kitti_00_times.txt"
    by_url, on_disk = gate.run(specs, jobs=1, keep_reports=True)
    assert by_url.status == on_disk.status == "passed", (by_url.error, on_disk.error)
    assert by_url.report["parameters"] == on_disk.report["parameters"]


def test_urls_that_cannot_be_read_are_their_routes_errors(served, capsys, monkeypatch):
    base, _ = served
    monkeypatch.setenv("COLUMNS", "200")  # the table as wide as a terminal: no cell wrapped
    code = main(["batch", f"{base}/no_such_route.tum", "nosuchscheme://host/a.tum", f"{base}/figure_eight.tum",
                 "--min-score", "0"])
    out = capsys.readouterr().out
    assert code == 1
    assert f"{base}/no_such_route.tum: not found" in out
    assert "cannot read nosuchscheme://host/a.tum" in out and "Traceback" not in out
    assert "figure_eight.tum" in out and "pass" in out


def test_mine_a_log_by_url_finds_the_same_windows(served):
    base, d = served
    url, = gate.collect([f"{base}/figure_eight_control.csv"])
    local, = gate.collect([str(d / "figure_eight_control.csv")])
    a, b = (mine.mine_task(mine.Task(s, 30.0, None, 2, 10.0)) for s in (url, local))
    assert a.error is None and b.error is None, (a.error, b.error)
    assert [(w.start_s, w.end_s, w.score) for w in a.best] == [(w.start_s, w.end_s, w.score) for w in b.best]
    assert a.best[0].path == url.path


def test_a_bag_folder_by_url_is_copied_whole(data_dir):
    """A ROS 2 bag is a folder: its URL (here file://) is copied with every file below it."""
    folder = data_dir / "tf_example_ros2"
    spec_url = gate.RouteSpec(folder.as_uri(), "tf_example_ros2", "robotaxi", min_score=0.0, topic="/tf:odom.base_link")
    spec_dir = gate.RouteSpec(str(folder), "tf_example_ros2", "robotaxi", min_score=0.0, topic="/tf:odom.base_link")
    a, b = gate.evaluate_spec(spec_url, keep_report=True), gate.evaluate_spec(spec_dir, keep_report=True)
    assert a.error is None and b.error is None, (a.error, b.error)
    assert a.report["parameters"] == b.report["parameters"]


def test_a_large_file_from_a_server_without_range_requests(served, tmp_path):
    """Python's http.server answers no range requests: a file larger than fsspec's 5 MiB read
    block must still arrive whole (one streaming read)."""
    base, d = served
    big = d / "big.tum"
    lines = FIGURE_EIGHT.read_text().splitlines(keepends=True)
    with big.open("w") as out:
        while out.tell() < 6 * 2**20:
            out.writelines(lines)
    with remote.local(f"{base}/big.tum") as p:
        assert Path(p).read_bytes() == big.read_bytes()


def test_errors_name_the_url_not_the_copy(served, tmp_path):
    """A route that cannot be parsed, a JUnit report, a glob: the URL the user gave, never the
    temporary copy's path."""
    base, d = served
    (d / "bad.tum").write_text("0 0 0 0 0 0 0 1\n1 0 x 0 0 0 0 1\n")
    res, = gate.run(gate.collect([f"{base}/bad.tum"]), jobs=1)
    assert res.error.startswith(f"{base}/bad.tum, line 2") and "excite-fetch" not in res.error, res.error
    junit = tmp_path / "junit.xml"
    assert main(["batch", f"{base}/no_such.tum", "--junit", str(junit)]) == 1
    assert f"{base}/no_such.tum" in junit.read_text()
    with pytest.raises(RouteError, match="globs are not expanded in URLs"):
        with remote.local(f"{base}/*.tum"):
            pass


def test_the_copy_is_bounded_while_it_streams(served):
    base, _ = served
    with pytest.raises(RouteError, match="over the limit of 1000 bytes"):
        with remote.local(f"{base}/figure_eight.tum", max_bytes=1000):
            pass


def test_local_paths_pass_through_and_copies_are_removed(served):
    base, _ = served
    with remote.local("trajectories/figure_eight.tum") as p:
        assert p == "trajectories/figure_eight.tum"
    with remote.local(None) as p:
        assert p is None
    with remote.local(f"{base}/figure_eight.tum?x=1") as p:
        copy = Path(p)
        assert copy.name == "figure_eight.tum" and copy.read_bytes() == FIGURE_EIGHT.read_bytes()
    assert not copy.exists() and not copy.parent.exists()
