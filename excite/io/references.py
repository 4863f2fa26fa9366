"""The reference maneuvers as route files (``trajectories/``): ``python -m excite.io.references
--write DIR`` writes them; ``tests/motion/test_maneuvers.py`` holds the committed files to it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..motion.maneuvers import reference_maneuvers
from ..motion.vehicle import Suspension, drive
from .routes import write_control_csv, write_tum


def write_reference_files(out_dir: str | Path, duration_s: float = 90.0,
                          rate_hz: float = 10.0) -> list[Path]:
    """Write every reference maneuver (default limits, 80 × 50 m lot, default suspension) as
    ``<name>.tum`` (poses at ``rate_hz``) and ``<name>_control.csv``. Deterministic. The TUM files
    stand for logged drives: they are not marked already smooth, and are smoothed when read, as a
    log is."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, prof in reference_maneuvers(duration_s).items():
        written.append(write_control_csv(prof, out_dir / f"{name}_control.csv"))
        written.append(write_tum(drive(prof, Suspension()), out_dir / f"{name}.tum", rate_hz, as_log=True))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m excite.io.references",
                                     description="Write the reference maneuvers as route files.")
    parser.add_argument("--write", metavar="DIR", required=True, help="output folder")
    parser.add_argument("--duration", type=float, default=90.0, help="seconds per maneuver")
    args = parser.parse_args(argv)
    for path in write_reference_files(args.write, args.duration):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
