"""`excite mine`: windows combined from chunk summaries equal the exact evaluator on the crop,
the figure-eight in a straight hour is found, and the outputs (table, CSV, JSON, TUM and bag
crops) are what a calibration pipeline reads."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from excite.information import elimination
from excite.fleet import mine
from excite.io.bags import read_bag_route, write_bag
from excite.cli.app import main
from excite.score.evaluate import evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_tum, write_tum
from excite.motion.vehicle import ControlProfile, drive

RIG = load_rig("robotaxi")


def varied(duration_s: float):
    t = np.linspace(0.0, duration_s, int(duration_s / 2) + 1)
    return drive(ControlProfile(t, 8 + 3 * np.sin(t / 7), 0.05 * np.sin(t / 5) + 0.02 * np.sin(t / 1.7),
                                grade_rad=0.02 * np.sin(t / 23), name="varied"), RIG.suspension)


@pytest.fixture(scope="module")
def short_drive():
    traj = varied(150.0)
    return traj, mine.summarise(traj, RIG, chunk_s=5.0)


@pytest.mark.parametrize("L", [1, 4, 30])
def test_window_information_is_the_evaluators_on_the_crop(short_drive, L):
    """Λ_θ of windows of L chunks (the first, one split across two blocks, the last, which ends
    the drive) equals what the evaluator computes from the cropped drive itself."""
    traj, s = short_drive
    Lam, diag = mine.window_information(s, L)
    assert Lam.shape[0] == s.n_chunks - L + 1
    for i in sorted({0, min(5, Lam.shape[0] - 1), Lam.shape[0] - 1}):
        a, b = s.time(int(s.edges[i])), s.time(int(s.edges[i + L]))
        crop = traj.cropped(a, b)
        ref = elimination.drive_information([crop], RIG)
        assert ref.n_keyframes == s.edges[i + L] - s.edges[i] + 1
        scale = np.abs(ref.information).max()
        np.testing.assert_allclose(Lam[i], ref.information, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(diag[i], ref.diag_tt, rtol=1e-12)
        score, _ = mine._analysed(RIG, Lam[i], diag[i])
        assert score == pytest.approx(evaluate(crop, RIG).score, rel=1e-7)


def test_batched_scores_are_the_spectrum_analysis(short_drive):
    """The batched score and pass/fail that rank windows agree with spectrum.analyse (the
    evaluator's) on every window, with and without unobservable directions."""
    _, s = short_drive
    for L in (1, 2, 12):
        Lam, diag = mine.window_information(s, L)
        score, passed = mine.batch_scores(RIG, Lam, diag)
        for i in range(Lam.shape[0]):
            ref, sigma = mine._analysed(RIG, Lam[i], diag[i])
            assert score[i] == pytest.approx(ref, rel=1e-9, abs=0)
            targets = np.array([c.target for c in RIG.scored])
            assert passed[i] == bool(np.all(np.nan_to_num(sigma, nan=np.inf) <= targets))
    one_chunk, _ = mine.batch_scores(RIG, *mine.window_information(s, 1))
    assert (one_chunk == 0).any() and (one_chunk > 0).any() or (one_chunk > 0).all()


def test_a_crop_samples_the_whole_drive(short_drive):
    traj, _ = short_drive
    crop = traj.cropped(20.0, 50.0)
    t = np.linspace(20.0, 50.0, 31)
    np.testing.assert_array_equal(crop.sample(t).p_W_V, traj.sample(t).p_W_V)
    assert (crop.t_start, crop.t_end, crop.duration) == (20.0, 50.0, 30.0)
    with pytest.raises(ValueError, match="not inside the drive"):
        traj.cropped(-1.0, 10.0)


@pytest.fixture(scope="module")
def straight_hour_with_figure_eight():
    """An hour of straight road at a steady 10 m/s, with 60 s of figure-eights (alternating
    loops, varying speed) starting at 1800 s."""
    f0, f1 = 1800.0, 1860.0
    t = np.concatenate([np.arange(0.0, f0 - 10, 5.0), np.arange(f0 - 10, f1 + 10, 0.5), np.arange(f1 + 10, 3601.0, 5.0)])
    inside = (t >= f0) & (t <= f1)
    phase = 2 * np.pi * (t - f0) / 20.0
    curvature = np.where(inside, (1 / 12) * np.sin(phase), 0.0)
    speed = np.where(inside, 10.0 - 2.0 * np.sin(phase / 2) ** 2, 10.0)
    traj = drive(ControlProfile(t, speed, curvature, name="straight hour"), RIG.suspension)
    return traj, (f0, f1)


@pytest.mark.slow
def test_mine_finds_the_figure_eight_in_a_straight_hour(straight_hour_with_figure_eight):
    traj, (f0, f1) = straight_hour_with_figure_eight
    res = mine.mine(traj, RIG, window_s=120.0, goal=mine.Goal(min_score=1e-6), per_log=2)
    best = res.best[0]
    assert best.duration_s == pytest.approx(120.0)
    assert best.start_s <= f0 and best.end_s >= f1, "the best window holds the figure-eight"
    # its score is the exact evaluator's on that window (the crop: the same trajectory restricted
    # to the window's keyframes), computed here from scratch
    exact = evaluate(traj.cropped(best.start_s, best.end_s), RIG).score
    assert best.score == pytest.approx(exact, rel=1e-7) and exact > 0
    assert best.confirmed_score == pytest.approx(exact, rel=1e-12)
    # the runner-up cannot overlap it, and holds less of the figure-eight: a lower score
    second = res.best[1]
    assert second.end_s <= best.start_s or second.start_s >= best.end_s
    assert second.score < best.score
    far = evaluate(traj.cropped(600.0, 720.0), RIG).score  # two minutes of straight road
    assert far < 1e-3 * best.score
    # the shortest window reaching the goal lies on the figure-eight and reaches the goal exactly
    short = res.shortest
    assert short is not None and short.duration_s <= best.duration_s
    assert short.start_s < f1 and short.end_s > f0
    assert evaluate(traj.cropped(short.start_s, short.end_s), RIG).score >= 1e-6
    assert res.windows_evaluated > 700


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Two logs: a bag (ROS 2, MCAP) of a varied drive and a TUM file of the same drive's first
    100 s (a weaker log)."""
    d = tmp_path_factory.mktemp("logs")
    traj = varied(160.0)
    bag = write_bag(traj, d / "drive_bag", topic="/odom", rate_hz=50.0)
    tum = d / "short.tum"
    write_tum(traj.cropped(0.0, 100.0), tum, rate_hz=50.0)
    return bag, tum


def test_cli_outputs_and_crops(logs, tmp_path, capsys):
    bag, tum = logs
    out_csv, out_json, crops = tmp_path / "w.csv", tmp_path / "w.json", tmp_path / "crops"
    code = main(["mine", str(bag), str(tum), "--topic", "/odom", "--window", "60", "--chunk", "10",
                 "--csv", str(out_csv), "--json", str(out_json), "--crop", str(crops), "--jobs", "1"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "best windows of 60 s (whole 10 s chunks)" in text and "2 logs mined" in text
    rows = list(csv.DictReader(out_csv.open()))
    assert [r["log"] for r in rows][0].endswith("drive_bag") or "drive_bag" in rows[0]["path"]
    assert {"log", "start_s", "end_s", "score", "confirmed_score", "misses"} <= set(rows[0])
    scores = [float(r["score"]) for r in rows]
    assert scores == sorted(scores, reverse=True) and len(rows) == 2
    for r in rows:
        assert float(r["end_s"]) - float(r["start_s"]) == pytest.approx(60.0)
        assert float(r["confirmed_score"]) == pytest.approx(float(r["score"]), rel=1e-7)
    doc = json.loads(out_json.read_text())
    assert [w["score"] for w in doc["best"]] == scores
    assert all(entry["error"] is None for entry in doc["logs"])
    # the crops of the winner: TUM poses over the window, and the bag cut to the window
    win = rows[0]
    a, b = float(win["start_s"]), float(win["end_s"])
    tum_crop = next(crops.glob("*.tum"))
    cropped = read_tum(tum_crop)  # (the reader counts time from the first pose, like the log's)
    assert cropped.duration == pytest.approx(b - a)
    # read back, the crop scores what the window scored: its poses are not smoothed a second time
    # (which attenuated the motion: a crop once scored 14 % under its window)
    assert evaluate(cropped, RIG).score == pytest.approx(float(win["score"]), rel=0.01)
    bag_crop = next(p for p in crops.iterdir() if p.suffix != ".tum")
    from_bag = read_bag_route(bag_crop, "/odom")
    assert from_bag.duration == pytest.approx(b - a, abs=0.03)  # poses at 50 Hz
    assert evaluate(from_bag, RIG).score == pytest.approx(float(win["score"]), rel=0.02)  # smoothed once, cut
    whole = read_bag_route(bag, "/odom")
    # the same motion on both clocks: the displacement over the middle of the window (positions
    # are counted from each log's first pose)
    t = 0.5 * (b - a) + np.array([-10.0, 10.0])
    np.testing.assert_allclose(np.diff(from_bag.sample(t).p_W_V, axis=0), np.diff(whole.sample(a + t).p_W_V, axis=0),
                               atol=0.05)


def test_cli_goal_and_errors(logs, tmp_path, capsys):
    bag, tum = logs
    assert main(["mine", str(tum), "--window", "60", "--min-score", "1e9", "--jobs", "1"]) == 1
    out = capsys.readouterr().out
    assert "never reaches score ≥ 1e+09" in out and "shortest windows" not in out  # no empty table
    for args, message in ((["--window", "0"], "--window must be a duration > 0 s"),
                          (["--min-score", "1", "--targets"], "two goals"),
                          (["--per-log", "0"], "--per-log must be ≥ 1")):
        assert main(["mine", str(tum), *args]) == 1
        err = capsys.readouterr().err
        assert err.startswith("excite: error:") and message in err and err.count("\n") == 1
    assert main(["mine", str(tmp_path / "missing.tum"), "--jobs", "1"]) == 1
    assert "No such file" in capsys.readouterr().out
