"""Which module registers each ``excite`` command, and the command word of a command line.
Standard library only: the ``excite`` script (:mod:`.resident_process`) reads it before anything
else is imported."""

from __future__ import annotations

# command → the module that registers it on `app`
COMMANDS = {"batch": "batch", "live": "live", "mine": "mine", "optimize": "optimize", "resident": "resident",
            "route": "route", "rig": "rig_import", "score": "score", "serve": "serve", "validate": "validate"}


def command_of(argv: list[str]) -> str | None:
    """The command word of ``excite`` arguments (the root takes no option with a value)."""
    words = [a for a in argv if not a.startswith("-")]
    return words[0] if words else None
