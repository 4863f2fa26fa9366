"""What a path holds, told without reading it: whether a bag reader, or the comma2k19 reader, is
for it."""

from __future__ import annotations

from pathlib import Path


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a bag excite reads: ``.bag``, ``.mcap`` or a ROS 2 bag folder."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in (".bag", ".mcap")


def is_comma2k19(path: str | Path) -> bool:
    """Whether ``path`` is a comma2k19 segment folder (``processed_log/`` and ``global_pose/``)."""
    p = Path(path)
    return p.is_dir() and (p / "processed_log").is_dir() and (p / "global_pose").is_dir()
