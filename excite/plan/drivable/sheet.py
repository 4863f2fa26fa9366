"""The driver's sheet: the lot to scale with its cones, the numbered elements with arrows, and one
line of instructions per element, on one printable page (PDF or PNG).

Drawn with matplotlib's object API on an Agg canvas (no pyplot, no display), like the report's
figures: the CLI, the service's workers and a notebook can all call :func:`sheet`.
"""

from __future__ import annotations

import io
import math
import textwrap

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import FancyArrowPatch, Polygon

from .plan import Built

_COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"]
_CONE = "#f28e1c"


def sheet(built: Built, site, fmt: str = "png", title: str | None = None, notes: list[str] | None = None,
          dpi: int = 130) -> bytes:
    """The sheet of ``built`` in ``site`` as ``fmt`` (``png`` or ``pdf``) bytes: an A4 landscape
    page."""
    fig = Figure(figsize=(11.69, 8.27))
    ax = fig.add_axes((0.07, 0.30, 0.57, 0.62))
    _draw_lot(ax, site)
    legs = built.course.legs
    for k, leg in enumerate(legs):
        xy = leg.path.xyz_m[:, :2]
        if leg.element < 0:
            ax.plot(xy[:, 0], xy[:, 1], color="#888888", lw=1.0, ls=(0, (4, 3)), zorder=2)
            continue
        col = _COLOURS[leg.element % len(_COLOURS)]
        ax.plot(xy[:, 0], xy[:, 1], color=col, lw=1.6, zorder=3)
        _arrows(ax, xy, col)
        ax.annotate(str(leg.element + 1), xy[0], xytext=(xy[0, 0], xy[0, 1]), color="white", fontsize=10,
                    fontweight="bold", ha="center", va="center", zorder=6,
                    bbox=dict(boxstyle="circle,pad=0.25", fc=col, ec="white", lw=1.2))
    for c in built.cones:
        ax.plot(c.x, c.y, marker="^", ms=9, color=_CONE, mec="black", mew=0.6, zorder=5)
        ax.annotate(c.label, (c.x, c.y), xytext=(4, 4), textcoords="offset points", fontsize=7, zorder=6)
    if built.plan.entry is not None:
        ex, ey, eh = built.plan.entry
        ax.annotate("entry", (ex, ey), xytext=(ex - 6 * math.cos(eh), ey - 6 * math.sin(eh)),
                    arrowprops=dict(arrowstyle="->", color="black"), fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]" + (" (east)" if getattr(site, "origin", None) else ""))
    ax.set_ylabel("y [m]" + (" (north)" if getattr(site, "origin", None) else ""))
    ax.grid(True, lw=0.3, alpha=0.5)
    _scale_bar(ax, site)
    n = len(built.plan.elements)
    fig.suptitle(title or f"{built.plan.name}: {built.plan.duration_s:.0f} s, {n} element{'s' if n != 1 else ''}, "
                 f"{len(built.cones)} cones", x=0.04, ha="left", fontsize=13, fontweight="bold")

    # the instructions: one line per element, wrapped
    tx = fig.add_axes((0.66, 0.06, 0.32, 0.86))
    tx.axis("off")
    y = 1.0
    tx.text(0, y, "Instructions", fontsize=11, fontweight="bold", va="top")
    y -= 0.045
    lines = [f"Set out the cones as drawn ({len(built.cones)}: ▲, numbered). Drive from rest to rest; "
             "between elements (dashed) drive at about "
             f"{built.plan.transit_speed_mps * 3.6:.0f} km/h to the next start (●) and stop facing the arrow."]
    for i, text in enumerate(built.instructions):
        lines.append(f"{i + 1}. {text}.")
    for k, text in enumerate(lines):
        wrapped = textwrap.wrap(text, 58)
        col = "black" if k == 0 else _COLOURS[(k - 1) % len(_COLOURS)]
        for j, w in enumerate(wrapped):
            tx.text(0, y, w, fontsize=8.2, va="top", color=col if j == 0 or k == 0 else "black",
                    fontweight="bold" if (j == 0 and k > 0) else "normal")
            y -= 0.028
        y -= 0.012
    # the targets table under the lot
    tb = fig.add_axes((0.04, 0.04, 0.60, 0.20))
    tb.axis("off")
    rows = [["#", "element", "target speed", "laps", "stop after"]]
    for i, e in enumerate(built.plan.elements):
        laps = int(e.params.get("laps", 1))
        rows.append([str(i + 1), e.kind.replace("_", " "), f"{built.speeds_kmh[i]:.0f} km/h", str(laps),
                     f"{e.dwell_s:.0f} s" if e.dwell_s >= 1.0 else "—"])
    table = tb.table(cellText=rows, loc="upper left", colWidths=[0.05, 0.3, 0.2, 0.1, 0.15], cellLoc="left")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    for (r, _), cell in table.get_celld().items():
        cell.set_linewidth(0.3)
        if r == 0:
            cell.set_text_props(fontweight="bold")
    if notes:
        tb.text(0.0, -0.05, "  ".join(notes), fontsize=7.5, va="top", transform=tb.transAxes, color="#444444")
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    return buf.getvalue()


def _draw_lot(ax, site) -> None:
    outline = site.lot.polygon_m
    ax.add_patch(Polygon(outline, closed=True, fc="#f4f4f0", ec="black", lw=1.5, zorder=0))
    for h in site.lot.holes:
        ax.add_patch(Polygon(h, closed=True, fc="#bbbbbb", ec="black", lw=1.0, hatch="//", zorder=1))
    for f in site.terrain.features:
        ax.add_patch(Polygon(f.polygon_m, closed=True, fc="#d9ead3", ec="#6aa84f", lw=0.8, zorder=1))
        c = np.asarray(f.polygon_m).mean(axis=0)
        ax.text(c[0], c[1], f.role, fontsize=7, ha="center", color="#38761d", zorder=1)
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    pad = 0.04 * float((hi - lo).max())
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)


def _arrows(ax, xy: np.ndarray, col: str, every_m: float = 25.0) -> None:
    """Arrows along a path every ``every_m`` (its direction of travel)."""
    d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    if d[-1] < 2.0:
        return
    marks = np.arange(every_m / 2, d[-1], every_m)
    seen: list[np.ndarray] = []
    for m in marks:
        i = int(np.searchsorted(d, m))
        j = min(i + 8, len(xy) - 1)
        if j <= i or any(np.linalg.norm(xy[i] - p) < 4.0 for p in seen):  # laps drawn once
            continue
        seen.append(xy[i])
        ax.add_patch(FancyArrowPatch(tuple(xy[i]), tuple(xy[j]), arrowstyle="-|>", mutation_scale=11, color=col,
                                     lw=0, zorder=4))


def _scale_bar(ax, site) -> None:
    lo = site.lot.polygon_m.min(axis=0)
    hi = site.lot.polygon_m.max(axis=0)
    span = float(hi[0] - lo[0])
    length = 10.0 if span < 120 else 50.0
    x0, y0 = lo[0], lo[1] - 0.03 * float((hi - lo).max())
    ax.plot([x0, x0 + length], [y0, y0], color="black", lw=3, solid_capstyle="butt", clip_on=False)
    ax.text(x0 + length / 2, y0, f"{length:.0f} m", ha="center", va="bottom", fontsize=7)
