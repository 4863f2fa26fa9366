"""How values are shown to people: the one table of display units, and lists of names in messages."""

from __future__ import annotations

import math

# SI unit → (factor, unit an engineer reads it in)
_DISPLAY = {"rad": (180 / math.pi, "deg"), "m": (100.0, "cm"), "s": (1e3, "ms"),
            "rad/s": (180 / math.pi, "deg/s"), "m/s^2": (1.0, "m/s²"), "1": (1.0, "")}


def display_unit(unit: str) -> tuple[float, str]:
    """(factor, name) of the unit values in SI ``unit`` are shown in: ``display_unit("m") == (100, "cm")``."""
    return _DISPLAY.get(unit, (1.0, unit))


def human(value: float | None, unit: str) -> str:
    """A value in SI ``unit`` as an engineer reads it (``0.5 cm``, ``0.05 deg``); None is unobservable."""
    if value is None:
        return "unobservable"
    f, u = display_unit(unit)
    return f"{value * f:.3g} {u}".strip()


MAX_LISTED = 40  # names a message lists (a bag may hold 20 000 topics)


def listed(names, limit: int = MAX_LISTED) -> str:
    """``a, b, c`` — at most ``limit`` names, then how many more."""
    names = list(names)
    head = ", ".join(names[:limit])
    return head + (f", … and {len(names) - limit:,} more" if len(names) > limit else "")
