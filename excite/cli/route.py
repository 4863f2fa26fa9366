"""``excite route ...``: inspect route files."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .app import app, console

route_app = typer.Typer(no_args_is_help=True, help="Inspect route files.")
app.add_typer(route_app, name="route")


def route_summary(traj, limits, rate_hz: float = 20.0) -> dict:
    """Duration, length and (min, max) of speed, longitudinal acceleration, yaw rate, pitch and
    roll of a trajectory, and its limit violations."""
    import numpy as np

    from ..core import so3
    from ..motion.vehicle import check_limits

    s = traj.sample(traj.times(rate_hz))
    ypr = so3.yaw_pitch_roll(s.R_W_V)

    def rng(x: "np.ndarray") -> tuple[float, float]:
        return float(np.min(x)), float(np.max(x))

    return {
        "duration_s": traj.duration,
        "length_m": traj.length_m(rate_hz),
        "ranges": {
            "speed [m/s]": rng(s.speed),
            "longitudinal acceleration [m/s²]": rng(s.accel_long),
            "yaw rate [deg/s]": rng(np.degrees(s.yaw_rate)),
            "pitch [deg]": rng(np.degrees(ypr[:, 1])),
            "roll [deg]": rng(np.degrees(ypr[:, 2])),
        },
        "violations": check_limits(traj, limits, rate_hz),
    }


def bag_table(file: Path) -> None:
    """What a bag holds and what excite can use of it, as a table."""
    from rich.table import Table
    from rich.text import Text

    from ..io.bags import bag_info

    topics = bag_info(file)
    table = Table(title=Text(f"{file.name}: {len(topics)} topics"))
    for col, just in (("topic", "left"), ("type", "left"), ("messages", "right"),
                      ("rate [Hz]", "right"), ("span \\[s]", "right"), ("use (excite score --topic / --imu-topic)", "left")):
        table.add_column(col, justify=just, overflow="fold")
    for t in topics:
        use = {"pose": f"--topic {t.topic}", "imu": f"--imu-topic {t.topic}",
               "tf": "\n".join(f"--topic {s}" for s in t.sources)}.get(t.use, "—")
        rate = "—" if t.rate_hz is None else f"{t.rate_hz:.3g}"
        table.add_row(Text(t.topic), Text(t.msgtype.replace("/msg/", "/")), str(t.count), rate,
                      f"{t.duration_s:.1f}", Text(use))
    console().print(table)


@route_app.command("info")
def info(file: Path = typer.Argument(..., help="Route file: .csv, .tum, .txt, .geojson, or a bag "
                                               "(.bag, .mcap, ROS 2 folder)"),
         times: Optional[Path] = typer.Option(None, "--times", help="KITTI times file"),
         rig: Optional[str] = typer.Option(None, "--rig", help="Bundled rig name or rig YAML path: "
                                           "its vehicle's limits too (a car's steering rate)"),
         ) -> None:
    """Duration, length, ranges of speed, acceleration, yaw rate, pitch and roll, and every
    limit violation (default limits; with ``--rig``, the tighter of those and the rig's vehicle's,
    as ``excite optimize`` plans within). For a bag: its topics, types, counts, rates and spans,
    and which can be scored (pose topics, TF chains) or give the IMU."""
    from rich.table import Table
    from rich.text import Text

    from ..io.bags import is_bag
    from ..io.routes import read_route
    from ..motion.vehicle import Limits, Suspension

    if is_bag(file):
        return bag_table(file)

    limits, suspension = Limits(), Suspension()
    if rig is not None:
        from ..plan.settings import vehicle_limits
        from ..rig.config import load_rig

        r = load_rig(rig)
        limits, suspension = vehicle_limits(r, limits), r.suspension
    traj = read_route(file, times=times, limits=limits, suspension=suspension)
    summary = route_summary(traj, limits)
    out_console = console()
    table = Table(title=Text(f"{file.name}: {summary['duration_s']:.1f} s, {summary['length_m']:.1f} m"))
    table.add_column("quantity")
    table.add_column("min", justify="right")
    table.add_column("max", justify="right")
    for name, (lo, hi) in summary["ranges"].items():
        table.add_row(Text(name), f"{lo:.3g}", f"{hi:.3g}")
    out_console.print(table)
    if summary["violations"]:
        out_console.print(f"{len(summary['violations'])} limit violation(s):")
        for v in summary["violations"]:
            out_console.print(f"  {v}", markup=False, highlight=False)
    else:
        out_console.print("within all limits")
