"""Golden reports: what excite says of the reference routes, KITTI 00 and two bags, held across
refactorings.

``tests/golden/reports.json`` holds σ, score, rank and the three spectra of every route, for the
bundled rig with random-walk biases and with constant biases; a change of structure (the factor
registry, how a drive is closed, how packages are cut) must reproduce it. Numbers are compared to
1e-7 relative: σ and the score each to its own size; a spectrum as a whole, to its largest
eigenvalue (its exactly-null entries are rounding noise of ~1e-13 of it, which no reordering of a
sum keeps to nine digits of their own). 1e-7, not 1e-9: other BLAS and LLVM kernels move the
worst-conditioned entries (the circles', with a track σ of 43 m) by up to ~5e-8, every other
entry by less than 1e-9, while a change of the model moves an entry by far more (≥ 1e-4).
A score (the smallest eigenvalue) is also allowed a rounding floor of 1e-14 of the largest
eigenvalue (~90 ε: a symmetric eigensolver's backward error is a few ε‖M‖, and M itself is a
sum over every keyframe), so where λ_min is ~1e-10 of λ_max (the circles: 1.3e-8 of 499) its
digits past ~4e-6 relative (ε‖M‖/λ_min) are rounding; elsewhere the floor is negligible (the
figure-eight: 3e-8 of its score).

Regenerate only on purpose (a model change, stated in the commit): ``EXCITE_UPDATE_GOLDEN=1
python3 -m pytest tests/score/test_golden.py``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from excite.score.evaluate import Options, evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_route
from helpers import REPO

GOLDEN = REPO / "tests" / "golden" / "reports.json"
TRAJ = REPO / "trajectories"
UPDATE = os.environ.get("EXCITE_UPDATE_GOLDEN") == "1"
RTOL = 1e-7
EIG_FLOOR = 1e-14


def _routes(data_dir: Path) -> dict[str, object]:
    from excite.io.bags import BagSource

    out = {p.name: (lambda p=p: read_route(p)) for p in sorted(TRAJ.glob("*.tum")) + sorted(TRAJ.glob("*.csv"))}
    out["kitti_00"] = lambda: read_route(data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt")
    out["ROS_example.bag:groundtruth"] = lambda: read_route(data_dir / "ROS_example.bag",
                                                            bag=BagSource(topic="groundtruth"))
    out["nav2_turtlebot.mcap:/odom"] = lambda: read_route(data_dir / "nav2_turtlebot.mcap",
                                                          bag=BagSource(topic="/odom"))
    return out


def _summary(rep) -> dict:
    out = {"score": rep.score, "rank": rep.rank, "nullity": rep.nullity,
           "sigma": {p.name: p.sigma for p in rep.parameters},
           "spectrum_scaled": rep.spectrum_scaled, "spectrum_unscaled": rep.spectrum_unscaled,
           "spectrum_normalised": rep.spectrum_normalised}
    if rep.segments:
        out["segment_scores"] = [s.score for s in rep.segments]
    return out


def _strided(rig):
    """The bundled rig at 20 Hz keyframes with the lidar at 10 Hz and the camera at 5 Hz (frame
    pairs two and four keyframes apart)."""
    sensors = [dict(s, rate_hz=rate) for s, rate in zip(rig.config.model_dump()["sensors"], (10.0, 5.0))]
    return rig.with_config(keyframe_rate_hz=20.0, sensors=sensors)


def _reports(data_dir: Path) -> dict:
    rig = load_rig("robotaxi")
    rigs = {"random_walk": rig, "constant": rig.with_constant_biases()}
    out = {}
    for name, read in _routes(data_dir).items():
        traj = read()
        for model, r in rigs.items():
            out[f"{name}|{model}"] = _summary(evaluate(traj, r))
        if name.endswith(".tum"):  # the reference maneuvers: strided sensors, and route segments
            out[f"{name}|strided"] = _summary(evaluate(traj, _strided(rig), Options(segments=7)))
    return out


def _close(a: float | None, b: float | None, scale: float, floor: float = 0.0) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return abs(a - b) <= RTOL * scale + floor


def test_the_reports_match_the_golden_file(data_dir):
    got = _reports(data_dir)
    if UPDATE:
        GOLDEN.parent.mkdir(exist_ok=True)
        GOLDEN.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        pytest.skip(f"wrote {GOLDEN}")
    want = json.loads(GOLDEN.read_text())
    assert sorted(got) == sorted(want)
    bad = []
    for key, w in want.items():
        g = got[key]
        if (g["rank"], g["nullity"]) != (w["rank"], w["nullity"]):
            bad.append(f"{key}: rank {g['rank']}/{g['nullity']}, golden {w['rank']}/{w['nullity']}")
        floor = EIG_FLOOR * max(w["spectrum_scaled"])  # the eigensolver's rounding of λ_min
        if not _close(g["score"], w["score"], abs(w["score"]), floor):
            bad.append(f"{key}: score {g['score']!r}, golden {w['score']!r}")
        assert sorted(g["sigma"]) == sorted(w["sigma"]), key
        for i, (a, b) in enumerate(zip(g.get("segment_scores", []), w.get("segment_scores", []))):
            if not _close(a, b, abs(b)):
                bad.append(f"{key}: segment {i} score {a!r}, golden {b!r}")
        if len(g.get("segment_scores", [])) != len(w.get("segment_scores", [])):
            bad.append(f"{key}: {len(g.get('segment_scores', []))} segments, golden {len(w.get('segment_scores', []))}")
        for name, s in w["sigma"].items():
            if not _close(g["sigma"][name], s, abs(s or 0.0)):
                bad.append(f"{key}: σ {name} {g['sigma'][name]!r}, golden {s!r}")
        for spec in ("spectrum_scaled", "spectrum_unscaled", "spectrum_normalised"):
            a, b = np.array(g[spec]), np.array(w[spec])
            if a.shape != b.shape or np.abs(a - b).max() > RTOL * np.abs(b).max():
                bad.append(f"{key}: {spec} differs by {np.abs(a - b).max() / np.abs(b).max():.2e} of its largest")
    assert not bad, "\n".join(bad[:30])
