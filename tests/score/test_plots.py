"""Figures: PNG bytes, every axis labelled with units, parameter names and unobservable ones
marked, the colour scale explained; ``excite score --plot`` writes one."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from excite.score import plots
from excite.cli.app import main
from excite.errors import PlotError
from excite.score.evaluate import Options, evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_route
from helpers import REPO

TRAJ = REPO / "trajectories"


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


def scored(name: str, rig, segments: bool = True):
    traj = read_route(TRAJ / name, suspension=rig.suspension)
    n = plots.segment_count(traj.duration) if segments else 0
    return evaluate(traj, rig, Options(segments=n)), traj


@pytest.fixture(scope="module")
def figure_eight(rig):
    return scored("figure_eight_control.csv", rig)


@pytest.fixture(scope="module")
def highway(rig):
    return scored("highway_run_control.csv", rig)


def texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


def test_report_figure_is_a_png_of_the_asked_size(figure_eight):
    rep, traj = figure_eight
    png = plots.report_figure(rep, traj, dpi=50, size_in=(15, 9))
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    img = imread(io.BytesIO(png))
    assert img.shape[:2] == (450, 750)
    assert img[..., :3].std() > 0.1  # not blank


def test_panels_are_labelled_with_units(figure_eight):
    rep, traj = figure_eight
    fig = plots.build_figure(rep, traj)
    route, cbar, spectrum, sigmas = fig.axes
    assert (route.get_xlabel(), route.get_ylabel()) == ("x [m]", "y [m]")
    assert route.get_aspect() == 1.0
    assert "weakest mode (cam_front.trans_z" in route.get_title()
    label = cbar.get_ylabel()
    assert "(target/σ)²" in label and "s segment alone" in label and "dimensionless" in label
    assert spectrum.get_yscale() == "log" and "eigenvalue λ of S·Λ·S" in spectrum.get_ylabel()
    assert "dimensionless" in spectrum.get_ylabel() and "weakest first" in spectrum.get_xlabel()
    legend = [t.get_text() for t in spectrum.get_legend().get_texts()]
    assert "#1: cam_front.trans_z +1.00" in legend
    assert any(abs(line.get_ydata()[0] - 1.0) < 1e-12 for line in spectrum.lines if len(line.get_ydata()) == 2)
    assert sigmas.get_xscale() == "log" and "σ / target" in sigmas.get_xlabel()
    ticks = [t.get_text() for t in sigmas.get_yticklabels()]
    assert ticks[0] == "lidar.rot_x  (target 0.05 deg)" and ticks[-1] == "wheel.track  (target 0.5 cm)"
    assert {t.split("  ")[0] for t in ticks} == {p.name for p in rep.parameters}
    assert "unobservable" not in texts(sigmas)


def test_unobservable_parameters_and_modes_are_marked(highway):
    rep, traj = highway
    fig = plots.build_figure(rep, traj)
    route, spectrum, sigmas = fig.axes  # no colour bar: nothing to colour along a null mode
    n_null = sum(p.sigma is None for p in rep.parameters)
    assert n_null == 4 and texts(sigmas).count("unobservable") == n_null
    assert "is unobservable" in route.get_title()
    legend = " ".join(t.get_text() for t in spectrum.get_legend().get_texts())
    assert "unobservable" in legend
    null_names = [m.coordinates[0][0] for m in rep.weak_modes if m.status == "unobservable"]
    assert ", ".join(null_names) in texts(spectrum) and "wheel.track" in null_names


def test_route_coloured_by_a_parameter(highway):
    rep, traj = highway
    fig = plots.build_figure(rep, traj, "wheel.radius_left")
    route, cbar = fig.axes[:2]
    assert route.get_title() == "where the route determines wheel.radius_left"
    values = np.concatenate([c.get_array() for c in route.collections if c.get_array() is not None])
    assert values.min() > 0 and cbar.get_yscale() == "log"
    with pytest.raises(PlotError, match="no parameter 'wheel.radius'"):
        plots.build_figure(rep, traj, "wheel.radius")


def test_report_without_segments_draws_the_route_plainly(rig):
    rep, traj = scored("slalom_control.csv", rig, segments=False)
    fig = plots.build_figure(rep, traj)
    assert "no segment information" in fig.axes[0].get_title()
    with pytest.raises(PlotError, match="one drive"):
        plots.build_figure(rep, [traj, traj])


def test_segment_count_bounds():
    assert plots.segment_count(90) == 45
    assert plots.segment_count(5) == 10 and plots.segment_count(4000) == 200


def test_score_plot_option_writes_the_png(tmp_path: Path, capsys):
    out = tmp_path / "f8.png"
    assert main(["score", str(TRAJ / "figure_eight_control.csv"), "--plot", str(out),
                 "--plot-parameter", "wheel.track"]) == 0
    assert out.read_bytes()[:4] == b"\x89PNG"
    printed = capsys.readouterr().out
    assert "Information per route segment" not in printed  # segments were for the plot only
    assert main(["score", str(TRAJ / "figure_eight_control.csv"), "--plot", str(out),
                 "--plot-parameter", "wheel.trak"]) == 2
    assert "--plot-parameter" in capsys.readouterr().err
    jpg = tmp_path / "f8.jpg"  # PNG bytes under another name: refused before any work
    assert main(["score", str(TRAJ / "figure_eight_control.csv"), "--plot", str(jpg)]) == 2
    assert "name the file .png" in capsys.readouterr().err and not jpg.exists()
