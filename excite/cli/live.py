"""``excite live``: guidance while the calibration drive happens (:mod:`excite.score.live`)."""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Iterator, Optional

import typer

from . import seeing
from .app import app, console

if TYPE_CHECKING:
    import numpy as np

_BATCH_S = 0.2  # poses are handed to the evaluator in batches of about this much drive time
_POLL_S = 0.05  # how often a followed file is polled for new lines


def _speed(text: str | None) -> float | None:
    if text is None:
        return None
    try:
        value = float(text.strip().lower().removesuffix("x"))
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"expected a positive speed factor such as 20x, got {text!r}",
                                 param_hint="--replay")
    return value


class _Lines:
    """Pose lines → (t, p, R) rows: TUM order ``t x y z qx qy qz qw`` (whitespace or commas), or
    KITTI's 12 numbers with the next time of a times file; ``#`` comments and blank lines skipped.
    Rows are converted exactly as the batch readers convert a file (:mod:`excite.io.routes`)."""

    def __init__(self, source: str, times: list[float] | None):
        self.source, self.times, self.line = source, times, 0

    def parse(self, raw: str) -> tuple[float, list[float]] | None:
        from ..errors import RouteError
        from ..io.routes import is_number

        self.line += 1
        text = raw.strip()
        if not text or text.startswith("#"):
            return None
        fields = text.replace(",", " ").split()
        try:
            numbers = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not is_number(f))
            raise RouteError(f"cannot parse {bad!r} as a number", source=self.source, line=self.line) from None
        if not all(math.isfinite(x) for x in numbers):
            raise RouteError("a number is not finite", source=self.source, line=self.line)
        if len(numbers) == 12:
            if self.times is None:
                raise RouteError("12 numbers (a KITTI pose) need --times", source=self.source, line=self.line)
            if not self.times:
                raise RouteError("more poses than times in the --times file", source=self.source, line=self.line)
            return self.times.pop(0), numbers
        if len(numbers) != 8:
            raise RouteError(f"expected 8 columns (t x y z qx qy qz qw) or 12 (KITTI), got {len(numbers)}",
                             source=self.source, line=self.line)
        return numbers[0], numbers[1:]

    def rows(self, parsed: list[tuple[float, list[float]]]) -> tuple["np.ndarray", "np.ndarray", "np.ndarray"]:
        import numpy as np
        from scipy.spatial.transform import Rotation

        from ..errors import RouteError
        from ..io.poses import QUAT_NORM_TOL, R_CAM_VEH, ROTATION_TOL

        t = np.array([r[0] for r in parsed])
        d = np.array([r[1] for r in parsed])
        if d.shape[1] == 12:
            T = d.reshape(-1, 3, 4)
            R_W_C = T[:, :, :3]
            err = np.abs(np.swapaxes(R_W_C, 1, 2) @ R_W_C - np.eye(3)).max(axis=(1, 2))
            if np.any(err > ROTATION_TOL) or np.any(np.linalg.det(R_W_C) <= 0):
                raise RouteError("a 3x3 block is not a rotation", source=self.source, line=self.line)
            R = Rotation.from_matrix(R_CAM_VEH.T @ R_W_C @ R_CAM_VEH).as_matrix()
            return t, T[:, :, 3] @ R_CAM_VEH, R
        q = d[:, 3:7]
        norm = np.linalg.norm(q, axis=1)
        if np.any(np.abs(norm - 1.0) > QUAT_NORM_TOL):
            raise RouteError(f"a quaternion has norm {norm[np.argmax(np.abs(norm - 1))]:.6g}, not 1",
                             source=self.source, line=self.line)
        return t, d[:, :3], Rotation.from_quat(q / norm[:, None]).as_matrix()


def _batches_of_lines(lines: Iterator[str | None], parser: _Lines) -> Iterator[tuple]:
    """Batches of rows from a stream of lines (None: nothing new right now, hand over what there is)."""
    batch: list[tuple[float, list[float]]] = []
    for raw in lines:
        row = None if raw is None else parser.parse(raw)
        if row is not None:
            batch.append(row)
        if batch and (raw is None or batch[-1][0] - batch[0][0] >= _BATCH_S):
            yield parser.rows(batch)
            batch = []
    if batch:
        yield parser.rows(batch)


def _follow(path: Path, idle_s: float) -> Iterator[str | None]:
    """Lines of a file that may still grow; ends after ``idle_s`` without a new line."""
    with open(path, encoding="utf-8") as fh:
        partial, quiet = "", 0.0
        while True:
            chunk = fh.readline()
            if chunk:
                partial += chunk
                if partial.endswith("\n"):
                    yield partial
                    partial, quiet = "", 0.0
                continue
            if quiet >= idle_s:
                if partial:
                    yield partial
                return
            yield None
            time.sleep(_POLL_S)
            quiet += _POLL_S


def _stdin() -> Iterator[str | None]:
    for line in sys.stdin:
        yield line
    return


def _paced(t: "np.ndarray", p: "np.ndarray", R: "np.ndarray", speed: float) -> Iterator[tuple]:
    """Recorded poses handed over as a drive at ``speed`` times real time would deliver them."""
    import numpy as np

    start = time.monotonic()
    i, n = 0, t.size
    while i < n:
        due = t[0] + (time.monotonic() - start) * speed
        j = max(i + 1, int(np.searchsorted(t, due, side="right")))
        yield t[i:j], p[i:j], R[i:j]
        i = j
        if i < n:
            time.sleep(max(0.0, min(_BATCH_S, (t[i] - t[0]) / speed - (time.monotonic() - start))))


def _source(route: Path, times: Optional[Path], replay: float | None, topic: Optional[str],
            idle_s: float) -> tuple[Iterator[tuple], str]:
    """(batches of (t, p, R), name) of a source."""
    import numpy as np

    from ..io.bags import is_bag, read_poses
    from ..errors import RouteError

    if str(route) == "-":
        if replay is not None:
            raise typer.BadParameter("stdin is read as it comes: --replay is for files and bags", param_hint="--replay")
        return _batches_of_lines(_stdin(), _Lines("<stdin>", _times(times))), "stdin"
    if not route.exists():
        raise RouteError("no such file", source=str(route))
    if is_bag(route):
        if topic is None:
            raise typer.BadParameter("a bag needs --topic (the pose topic or /tf:PARENT.CHILD)", param_hint="--topic")
        s = read_poses(route, topic)
        name = f"{route.stem if route.is_file() else route.name}:{topic}"
        return _paced(s.t_s, np.asarray(s.p, float), s.R, replay or 1.0), name
    parser = _Lines(str(route), _times(times))
    if replay is None:
        return _batches_of_lines(_follow(route, idle_s), parser), route.stem
    rows = [r for r in (parser.parse(line) for line in route.read_text(encoding="utf-8").splitlines()) if r]
    if not rows:
        raise RouteError("the file has no poses", source=str(route))
    t, p, R = parser.rows(rows)
    return _paced(t, p, R, replay), route.stem


def _times(path: Optional[Path]) -> list[float] | None:
    if path is None:
        return None
    from ..io.routes import document, numbers, split_rows

    return [float(x) for x in numbers(split_rows(document(path), None), (1,))[:, 0]]


def _table(update: dict[str, Any], rig_name: str) -> Any:
    from rich.console import Group
    from rich.markup import escape
    from rich.progress_bar import ProgressBar
    from rich.table import Table
    from rich.text import Text

    from ..core.units import human

    kind = "final (the batch evaluator on every pose)" if update["type"] == "final" else "live"
    where = seeing.line(update.get("scene"))
    head = Text.from_markup(
        f"[bold]{kind}[/]  rig {rig_name}" + (f" in {escape(where)}" if where else "")
        + f"  t = {update['t_s']:.0f} s  {update['length_m'] / 1000:.2f} km  "
        f"score {update['score']:.3g}  " + ("[green]every parameter within target[/]" if update["passed"]
                                           else "[yellow]not yet[/]"))
    t = Table(box=None, pad_edge=False)
    t.add_column("parameter")
    t.add_column("progress", width=22)
    t.add_column("%", justify="right")
    t.add_column("σ", justify="right")
    t.add_column("target", justify="right")
    t.add_column("ETA", justify="right")
    t.add_column("what it needs", overflow="fold")
    for p in update["parameters"]:
        pct = 100 * p["progress"]
        eta = "" if p["eta_s"] is None else ("—" if p["status"] == "needs" else f"{p['eta_s']:.0f} s")
        style = {"ok": "green", "gaining": "yellow", "needs": "red"}[p["status"]]
        t.add_row(p["name"], ProgressBar(total=100, completed=pct, width=20, complete_style=style,
                                          finished_style="green"),
                  f"{pct:.0f}", human(p["sigma"], p["unit"]) if p["sigma"] is not None else "—",
                  human(p["target"], p["unit"]), eta, "" if p["status"] == "ok" else (p["advice"] or ""))
    parts: list[Any] = [head, t]
    if update["weakest"]:
        parts.append(Text(f"weakest direction: {update['weakest']['advice']}"))
    return Group(*parts)


_PLAN_EVENTS = ("element", "element_done", "element_short", "proposal")


def _plan_line(u: dict[str, Any]) -> str:
    """One line for a plan event (``excite live --plan``)."""
    t = f"t {u['t_s']:6.0f} s  "
    if u["type"] == "element":
        nxt = u["next"]
        return (t + f"element {u['element']}: {u['instruction']}"
                + (f"  — next: element {nxt['element']}" if nxt else "  — the plan's last element"))
    if u["type"] == "element_done":
        return t + f"element {u['element']} done ({u['laps_done']:.1f} of {u['laps_planned']} laps)"
    if u["type"] == "element_short":
        return t + f"element {u['element']} left after {u['laps_done']:.1f} of {u['laps_planned']} laps"
    steps = "; then ".join(f"element {r['element']}: {r['instruction']}" for r in u["remainder"]) or "nothing fits"
    return (t + f"proposal ({u['reason']}): {steps} — predicted score {u['predicted_score']:.3g} against the goal "
            f"{u['goal']:.3g} ({u['predicted_score_original']:.3g} with the plan's remainder)")


class _LogLines:
    """Updates as lines (output that is not a terminal): time, distance, score, parameters within
    target, the furthest-behind parameter and what it needs."""

    def __init__(self, out: Any):
        self.out = out

    def line(self, u: dict[str, Any]) -> None:
        ps = u["parameters"]
        ok = sum(p["status"] == "ok" for p in ps)
        worst = min(ps, key=lambda p: p["progress"])
        tail = "" if worst["status"] == "ok" else f"  lowest {worst['name']} {100 * worst['progress']:.0f} %: {worst['advice']}"
        self.out.print(f"t {u['t_s']:6.0f} s  {u['length_m'] / 1000:5.2f} km  score {u['score']:.3g}  "
                       f"{ok}/{len(ps)} within target{tail}", markup=False, highlight=False)


@app.command()
def live(
    route: Annotated[Path, typer.Argument(help="Pose source: a TUM/CSV file (followed as it grows, "
                                                "or replayed with --replay), - for stdin lines, or "
                                                "a bag (.bag, .mcap, ROS 2 folder) with --topic.")],
    times: Annotated[Optional[Path], typer.Option(help="KITTI times file (for 12-number pose lines).")] = None,
    rig: Annotated[str, typer.Option(help="Bundled rig name or rig YAML path.")] = "robotaxi",
    replay: Annotated[Optional[str], typer.Option(
        help="Replay a recorded file or bag at this speed (e.g. 20x) instead of following it.")] = None,
    topic: Annotated[Optional[str], typer.Option(help="Bags: the pose topic or TF chain /tf:PARENT.CHILD.")] = None,
    idle: Annotated[float, typer.Option(help="A followed file has ended after this many seconds "
                                             "without a new line.")] = 5.0,
    json_out: Annotated[bool, typer.Option("--json", help="Print one JSON object per update.")] = False,
    plan: Annotated[Optional[Path], typer.Option("--plan", help="The drivable plan being driven (plan.json of "
                                                 "excite optimize --drivable): say which element is being driven "
                                                 "and which is next, and when an element is cut short or the plan "
                                                 "ends short of its goal, what to repeat.")] = None,
    scene: Annotated[Optional[str], typer.Option(help=seeing.HELP)] = None,
) -> None:
    """Live guidance during the drive: each parameter's progress to its target, the motion it
    still needs, and done. Exit code 0 when every parameter is within target, 1 when the source
    ends first (after the final update, which is `excite score` on the same poses). When nothing
    more is gained from the motion so far, it says which parameters need which motion, and goes on."""
    from ..score.live import PoseStream
    from ..rig.config import load_rig

    if not (math.isfinite(idle) and idle > 0):
        raise typer.BadParameter(f"must be positive, got {idle}", param_hint="--idle")
    speed = _speed(replay)
    r = load_rig(rig)
    world = seeing.load(scene)
    seeing.warn_blind(r, world)
    batches, name = _source(route, times, speed, topic, idle)
    from ..io.poses import DEFAULT_CUTOFF_HZ
    from ..io.routes import already_smooth

    # a TUM file excite wrote is read as read_tum reads it: not smoothed a second time
    smooth = str(route) != "-" and route.is_file() and already_smooth(route)
    cutoff = math.inf if smooth else DEFAULT_CUTOFF_HZ
    if plan is not None:
        from ..plan.drivable.guide import PlanStream
        from ..plan.drivable.plan import read_plan

        stream = PlanStream(r, read_plan(plan), name=name, cutoff_hz=cutoff, scene=world)
    else:
        stream = PoseStream(r, name=name, cutoff_hz=cutoff, scene=world)
    out = console()

    def emit(update: dict[str, Any], display: Any) -> None:
        if json_out:
            typer.echo(json.dumps(update, separators=(",", ":")))
        elif update["type"] in _PLAN_EVENTS:
            out.print(_plan_line(update), markup=False, highlight=False)
        elif update["type"] == "done" and update["passed"]:
            out.print(f"[bold green]done[/] at t = {update['t_s']:.0f} s: {update['reason']}")
        elif update["type"] == "done":  # nothing more to gain from this motion: say what helps
            out.print(f"[bold yellow]nothing more to gain[/] at t = {update['t_s']:.0f} s from the motion so far; "
                      "change it or stop:")
            for n in update["needs"]:
                out.print(f"  {n['name']}: {n['advice']}", markup=False)
        elif isinstance(display, _LogLines):
            display.line(update)
        elif display is not None:
            display.update(_table(update, r.name))

    def run(display: Any) -> bool:
        for t, p, R in batches:
            for update in stream.add(t, p, R):
                emit(update, display)
                if update["type"] == "done" and update["passed"]:
                    return True
        return False

    if json_out:
        done = run(None)
    elif not out.is_terminal:  # a log: one line per update
        done = run(_LogLines(out))
    else:
        from rich.live import Live

        with Live(console=out, auto_refresh=False) as display:
            class _Refresh:
                def update(self, renderable: Any) -> None:
                    display.update(renderable, refresh=True)
            done = run(_Refresh())
        out.print()
    if done:
        raise typer.Exit(0)
    final = stream.finish()
    if json_out:
        typer.echo(json.dumps(final, separators=(",", ":")))
    else:
        out.print(_table(final, r.name))
        out.print("[bold green]done[/]" if final["done"] else "[red]the source ended before every parameter "
                                                                "reached its target[/]")
    raise typer.Exit(0 if final["done"] else 1)
