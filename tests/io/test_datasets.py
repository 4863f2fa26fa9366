"""The catalogue of public recordings (:mod:`excite.io.datasets`), offline: the local copy in
../shared/data is what the catalogue describes (size and SHA-256 of every file), and a fetch
served from that copy (no network) writes exactly those files, skips what is already intact,
refuses a file that arrives different and leaves nothing partial behind."""

from __future__ import annotations

import hashlib
import io
import urllib.parse

import pytest

from excite.cli.app import main
from excite.errors import DataError
from excite.io import datasets


def _local_opener(data_dir, corrupt: str | None = None):
    """Serves each catalogue URL with the bytes of the local copy it names (the catalogue's own
    path, not the URL's), optionally flipping a byte of one file."""
    by_url = {f.url: f.path for d in datasets.DATASETS.values() for f in d.files}
    served = []

    def opener(url):
        path = by_url[url]
        served.append(path)
        data = (data_dir / path).read_bytes()
        if path == corrupt:
            data = bytes([data[0] ^ 1]) + data[1:]
        return io.BytesIO(data)

    return opener, served


def test_every_file_of_the_local_copy_is_the_catalogues(data_dir):
    for name in datasets.DATASETS:
        assert datasets.check(name, data_dir) == [], name


def test_the_catalogue_names_a_public_source_licence_and_pinned_url_for_every_file():
    for d in datasets.DATASETS.values():
        assert d.source and d.licence and d.files
        for f in d.files:
            u = urllib.parse.urlsplit(f.url)
            assert u.scheme == "https" and len(f.sha256) == 64 and f.size > 0
            assert any(len(part) == 40 and all(c in "0123456789abcdef" for c in part) for part in u.path.split("/")), \
                f"{f.url} is not pinned to a commit"


def test_fetch_from_the_local_copy_writes_checked_files_and_skips_intact_ones(data_dir, tmp_path):
    opener, served = _local_opener(data_dir)
    got = datasets.fetch("kitti_00", tmp_path, opener=opener)
    assert sorted(p.name for p in got) == ["kitti_00_poses.txt", "kitti_00_times.txt"]
    for f in datasets.dataset("kitti_00").files:
        assert hashlib.sha256((tmp_path / f.path).read_bytes()).hexdigest() == f.sha256
    assert datasets.check("kitti_00", tmp_path) == []
    served.clear()
    assert datasets.fetch("kitti_00", tmp_path, opener=opener) == [] and served == []


def test_a_damaged_download_is_refused_and_leaves_nothing(data_dir, tmp_path):
    opener, _ = _local_opener(data_dir, corrupt="kitti_00_times.txt")
    with pytest.raises(DataError, match=r"kitti_00_times.txt: https://\S+ gave 59033 bytes whose SHA-256"):
        datasets.fetch("kitti_00", tmp_path, opener=opener)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kitti_00_poses.txt"]  # no .part file


def test_a_damaged_local_file_is_named_by_check(data_dir, tmp_path):
    opener, _ = _local_opener(data_dir)
    datasets.fetch("nav2_turtlebot", tmp_path, opener=opener)
    p = tmp_path / "nav2_turtlebot.mcap"
    p.write_bytes(b"\0" + p.read_bytes()[1:])
    assert datasets.check("nav2_turtlebot", tmp_path) == [f"{p}: SHA-256 differs from the catalogue's"]
    (tmp_path / "nav2_turtlebot.mcap").unlink()
    assert datasets.check("nav2_turtlebot", tmp_path) == [f"{p}: missing"]


def test_an_unreachable_url_is_one_error_naming_file_and_url(tmp_path):
    def opener(url):
        raise OSError("Name or service not known")

    with pytest.raises(DataError, match=r"kitti_00_poses.txt: cannot download https://\S+: Name or service not known"):
        datasets.fetch("kitti_00", tmp_path, opener=opener)


def test_the_command_line_lists_checks_and_names_unknown_datasets(data_dir, capsys):
    assert main(["data", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in datasets.DATASETS) and "licence: MIT" in out
    assert main(["data", "check", "kitti_00", "--dir", str(data_dir)]) == 0
    assert "kitti_00: ok" in capsys.readouterr().out
    assert main(["data", "fetch", "kitti"]) == 1
    assert "excite: error: no dataset named 'kitti' (datasets: kitti_00," in capsys.readouterr().err
