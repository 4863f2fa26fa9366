"""Which module registers each ``excite`` command, and the command word of a command line.
Standard library only: the ``excite`` script (:mod:`.resident_process`) reads it before anything
else is imported."""

from __future__ import annotations

# command → the module that registers it on `app` (``serve`` is the service's own: the service sits
# above the command line and adds its command to it)
COMMANDS = {c: f"excite.cli.{m}" for c, m in {
    "batch": "batch", "data": "data", "live": "live", "mine": "mine", "optimize": "optimize", "resident": "resident",
    "route": "route", "rig": "rig_import", "score": "score", "validate": "validate"}.items()}
COMMANDS["serve"] = "api.command"


def command_of(argv: list[str]) -> str | None:
    """The command word of ``excite`` arguments (the root takes no option with a value)."""
    words = [a for a in argv if not a.startswith("-")]
    return words[0] if words else None
