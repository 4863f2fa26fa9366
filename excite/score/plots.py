"""Figures of a report: where the route carries information, the scaled spectrum, σ against target.

Drawn with matplotlib's object API on an Agg canvas (no pyplot, no display, no global backend
switch), so the CLI, a notebook and the HTTP service's worker threads can all call them.

- :func:`plot_route`: the route seen from above (x–y in metres, equal axes), each segment
  coloured by the information it carries on its own (:class:`~excite.score.evaluate.Segment`): on one
  parameter ``p``, ``diag(S Λ_seg S)_pp`` = (target/σ)² that segment alone would give if ``p``
  were the only unknown calibration parameter; on the weakest mode ``v`` of the whole route,
  ``vᵀ S Λ_seg S v``, the same along that direction. The trajectory over the segment is estimated
  (marginalised) either way. Log colour scale; the colour bar says which quantity it is. Where
  laps repeat, later laps are drawn over earlier ones. Along an unobservable weakest mode no
  segment carries information (the values are numerical noise): the route is drawn grey and
  the title says so.
- :func:`plot_spectrum`: eigenvalues of ``S Λ_θ S``, weakest first, log scale, with the pass line
  at 1 (σ = target along that direction) and the numerical-rank threshold.
- :func:`plot_sigmas`: Cramér–Rao σ / target per parameter (log), pass line at 1, unobservable
  parameters marked.
- :func:`report_figure`: the three panels as PNG bytes (what ``excite score --plot`` writes and
  what the service returns).

The report must carry segments for the route panel: evaluate with
``Options(segments=segment_count(traj.duration))`` (a report without segments draws the route
uncoloured and says so).
"""

from __future__ import annotations

import io
import math
from typing import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from ..errors import PlotError
from .evaluate import Report
from ..motion.trajectory import Trajectory
from ..core.units import human

__all__ = ["PlotError", "segment_count", "plot_route", "plot_spectrum", "plot_sigmas", "report_figure",
           "build_figure", "WEAKEST_MODE"]

WEAKEST_MODE = "weakest mode"
_OK, _FAIL, _NULL = "#2a9d4b", "#d1495b", "#6c757d"


def segment_count(duration_s: float, seconds_per_segment: float = 2.0) -> int:
    """How many route segments to evaluate for the route panel: one per ~2 s (a keyframe
    window long enough to see a turn or a brake), between 10 and 200."""
    return int(min(200, max(10, round(duration_s / seconds_per_segment))))


def _segment_values(report: Report, parameter: str | None) -> tuple[np.ndarray, str]:
    if parameter is None or parameter == WEAKEST_MODE:
        values = np.array([s.weakest_mode_information for s in report.segments])
        mode = report.weak_modes[0] if report.weak_modes else None
        what = "the route's weakest mode"
        if mode is not None:
            what += " (" + ", ".join(f"{n} {w:+.2f}" for n, w in mode.coordinates[:2]) + ")"
        return values, what
    names = [p.name for p in report.parameters]
    if parameter not in names:
        raise PlotError(f"no parameter {parameter!r} in this report (parameters: {', '.join(names)})")
    return np.array([s.parameter_information[parameter] for s in report.segments]), parameter


def plot_route(ax: Axes, report: Report, traj: Trajectory, parameter: str | None = None) -> None:
    """The route from above, coloured by the information each segment carries on ``parameter``
    (a coordinate name) or, by default, on the route's weakest mode (see the module docstring)."""
    if not isinstance(traj, Trajectory):
        raise PlotError("the route panel draws one drive; several drives calibrated together have "
                        "no single route to colour")
    t = np.linspace(traj.t_start, traj.t_end, max(200, int(traj.duration * 10) + 1))
    xy = traj.sample(t).p_W_V[:, :2]
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, alpha=0.3)
    ax.plot(*xy[0], marker="o", color="black", ms=6, zorder=4, label="start")
    ax.plot(*xy[-1], marker="s", color="black", mfc="white", ms=6, zorder=4, label="end")
    if not report.segments:
        ax.plot(xy[:, 0], xy[:, 1], color=_NULL, lw=2)
        ax.set_title("route (no segment information: evaluate with Options(segments=N))", fontsize=10)
        ax.legend(loc="best", fontsize=8)
        return
    weakest = report.weak_modes[0] if report.weak_modes else None
    if (parameter is None or parameter == WEAKEST_MODE) and weakest is not None and weakest.status == "unobservable":
        # information along a null direction is numerical noise: nothing to colour by
        ax.plot(xy[:, 0], xy[:, 1], color=_NULL, lw=2.5)
        ax.set_title(f"the weakest mode ({weakest.coordinates[0][0]}) is unobservable: no segment carries\n"
                     "information on it (colour by a parameter instead: --plot-parameter)", fontsize=10)
        ax.legend(loc="best", fontsize=8)
        return
    values, what = _segment_values(report, parameter)
    positive = values[values > 0]
    hi = float(positive.max()) if positive.size else 1.0
    lo = max(float(positive.min()) if positive.size else hi * 1e-6, hi * 1e-6)
    lines, colours = [], []
    for seg, v in zip(report.segments, values):
        m = (t >= seg.t_start_s) & (t <= seg.t_end_s)
        idx = np.flatnonzero(m)
        if idx.size == 0:
            continue
        idx = np.r_[max(idx[0] - 1, 0), idx]  # join up with the previous segment
        pts = xy[idx]
        lines.append(np.stack([pts[:-1], pts[1:]], axis=1))
        colours.append(np.full(len(pts) - 1, max(v, lo)))
    lc = LineCollection(np.concatenate(lines), cmap="viridis", norm=LogNorm(lo, hi), linewidths=3.5,
                        capstyle="round")
    lc.set_array(np.concatenate(colours))
    ax.add_collection(lc)
    ax.autoscale_view()
    seg_s = (report.segments[0].t_end_s - report.segments[0].t_start_s)
    cbar = ax.figure.colorbar(lc, ax=ax, fraction=0.046, pad=0.02)
    cbar.set_label(f"(target/σ)² from each {seg_s:.1g} s segment alone\n"
                   f"[dimensionless, log; 1 = σ at target]", fontsize=9)
    ax.set_title(f"where the route determines {what}", fontsize=10)
    ax.legend(loc="best", fontsize=8)


def plot_spectrum(ax: Axes, report: Report) -> None:
    """Eigenvalues of S·Λ·S, weakest first (log), with the pass line; the unobservable directions
    (found by the rank test on the normalised information) drawn at a floor below the rest."""
    w = np.asarray(report.spectrum_scaled, dtype=float)
    k = np.arange(1, w.size + 1)
    null = k <= report.nullity
    floor = min(1.0, float(w[~null].min()) if (~null).any() else 1.0) / 100.0
    shown = np.where(null, np.maximum(w, floor), w)
    ok = ~null & (w >= 1.0)
    weak = ~null & (w < 1.0)
    n_null = int(null.sum())
    ax.semilogy(k[ok], shown[ok], "o", color=_OK, label="σ within targets (λ ≥ 1)")
    ax.semilogy(k[weak], shown[weak], "o", color=_FAIL, label="weak (λ < 1)")
    if n_null:
        names = ", ".join(m.coordinates[0][0] for m in report.weak_modes[:n_null])
        ax.semilogy(k[null], shown[null], "x", color=_NULL, ms=8, mew=2,
                    label="unobservable (rank test; drawn at the floor)")
        ax.annotate(names, (n_null, floor), xytext=(10, 0), textcoords="offset points", va="center",
                    fontsize=8, color=_NULL)
    ax.axhline(1.0, color=_OK, ls="--", lw=1.2)
    ax.text(w.size + 0.5, 1.0, " pass: λ = 1", va="bottom", ha="right", fontsize=8, color=_OK)
    # the weakest observable modes by their dominant coordinates, in the legend (labels on the
    # points would collide: weak eigenvalues come in close pairs)
    for kk, mode in enumerate(report.weak_modes[n_null:n_null + 3], start=n_null + 1):
        if mode.status == "ok":
            break
        coords = ", ".join(f"{n} {w_:+.2f}" for n, w_ in mode.coordinates[:2])
        ax.plot([], [], " ", label=f"#{kk}: {coords}")
    ax.set_xlim(0.3, w.size + 0.7)
    ax.set_xlabel("mode (eigenvector of S·Λ·S), weakest first")
    ax.set_ylabel("eigenvalue λ of S·Λ·S\n[dimensionless: (target/σ)² along the mode]")
    ax.set_title(f"scaled spectrum: score λ_min = {report.score:.3g}, rank {report.rank}/{w.size}", fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(loc="best", fontsize=8, framealpha=0.9)


def plot_sigmas(ax: Axes, report: Report) -> None:
    """Cramér–Rao σ / target per parameter (log bars), pass line at 1, unobservable marked."""
    params = report.parameters
    ratios = [None if p.sigma is None else p.sigma / p.target for p in params]
    finite = [r for r in ratios if r is not None]
    hi = max([10.0] + [r * 3 for r in finite])
    lo = min([0.1] + [r / 3 for r in finite])
    y = np.arange(len(params))[::-1]
    for yi, p, r in zip(y, params, ratios):
        if r is None:
            ax.barh(yi, hi - lo, left=lo, color="white", edgecolor=_NULL, hatch="///", height=0.7)
            ax.text(math.sqrt(lo * hi), yi, "unobservable", va="center", ha="center", fontsize=8,
                    color="black", zorder=5, bbox=dict(facecolor="white", edgecolor="none", pad=0.5))
        else:
            ax.barh(yi, r - lo, left=lo, color=_OK if p.ok else _FAIL, height=0.7)
            ax.text(r * 1.08, yi, human(p.sigma, p.unit), va="center", ha="left", fontsize=7.5, zorder=5,
                    bbox=dict(facecolor="white", edgecolor="none", alpha=0.8, pad=0.3))
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ax.set_ylim(-0.6, len(params) - 0.4)
    ax.set_yticks(y)
    ax.set_yticklabels([f"{p.name}  (target {human(p.target, p.unit)})" for p in params], fontsize=8.5)
    ax.axvline(1.0, color="black", ls="--", lw=1.2)
    ax.set_xlabel("Cramér–Rao σ / target  [dimensionless, log; ≤ 1 passes]")
    ax.set_title("σ per parameter from the drive alone (bar end: σ)", fontsize=10)
    ax.grid(True, axis="x", which="major", alpha=0.3)
    ax.legend(handles=[Patch(color=_OK, label="σ ≤ target"), Patch(color=_FAIL, label="σ > target"),
                       Patch(facecolor="white", edgecolor=_NULL, hatch="///", label="unobservable")],
              loc="lower right", fontsize=8)


def report_figure(report: Report, traj: Trajectory | Sequence[Trajectory], parameter: str | None = None, *,
                  dpi: int = 100, size_in: tuple[float, float] = (15.0, 9.0)) -> bytes:
    """The route, spectrum and σ panels of ``report`` as PNG bytes.

    ``parameter``: colour the route by the information on this coordinate (default: on the
    route's weakest mode). ``traj`` is the drive the report was evaluated on.
    """
    fig = build_figure(report, traj, parameter, dpi=dpi, size_in=size_in)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def build_figure(report: Report, traj: Trajectory | Sequence[Trajectory], parameter: str | None = None, *,
                 dpi: int = 100, size_in: tuple[float, float] = (15.0, 9.0)) -> Figure:
    """The figure :func:`report_figure` renders (to save in another format or to inspect)."""
    if not isinstance(traj, Trajectory):
        trajs = list(traj)
        if len(trajs) != 1:
            raise PlotError("the figure draws one drive; several drives calibrated together have "
                            "no single route to colour")
        traj = trajs[0]
    fig = Figure(figsize=size_in, dpi=dpi, layout="constrained")
    gs = fig.add_gridspec(2, 2, width_ratios=[1.25, 1.0], height_ratios=[1.35, 1.0])
    plot_route(fig.add_subplot(gs[0, 0]), report, traj, parameter)
    plot_spectrum(fig.add_subplot(gs[1, 0]), report)
    plot_sigmas(fig.add_subplot(gs[:, 1]), report)
    verdict = "PASS" if report.passed else "FAIL"
    fig.suptitle(f"{report.route} with rig {report.rig}: {report.duration_s:.0f} s, {report.length_m:.0f} m, "
                 f"score {report.score:.3g} ({verdict})", fontsize=12, fontweight="bold")
    return fig
