"""``excite resident start|stop|status``: the resident process that answers the short commands
(:mod:`excite.cli.resident_process`)."""

from __future__ import annotations

import json
import sys
import time
from typing import Annotated

import typer

from . import resident_process as resident
from ..errors import ExciteError
from .app import app

resident_app = typer.Typer(no_args_is_help=True, help=(
    "The resident process: keeps excite loaded so that score, route, rig and batch start at once "
    "(started by the first of them at a terminal; EXCITE_RESIDENT=0 turns it off)."))
app.add_typer(resident_app, name="resident")


def _where() -> dict:
    if not sys.platform.startswith("linux"):
        raise ExciteError("the resident process runs on Linux only: here every command runs in its own process")
    try:
        return resident.paths_of(resident.key(), create=True)
    except OSError as exc:
        raise ExciteError(str(exc)) from None


@resident_app.command()
def start(idle_minutes: Annotated[float, typer.Option(
        help="Leave after this many minutes without a command.", min=0.01, max=7 * 24 * 60)] = resident.IDLE_MINUTES,
          ) -> None:
    """Start the resident process of this installation and wait until it answers."""
    paths = _where()
    running = resident.control("status")
    if running is not None:
        typer.echo(f"resident process {running['pid']} is already running (key {running['key']})")
        return
    t0 = time.monotonic()
    try:
        pid = resident.start(idle_minutes, wait_s=300.0)
    except RuntimeError as exc:
        raise ExciteError(str(exc)) from None
    typer.echo(f"resident process {pid} ready after {time.monotonic() - t0:.1f} s; it leaves after "
               f"{idle_minutes:g} minutes without a command (log: {paths['log']})")


@resident_app.command()
def stop() -> None:
    """Stop the resident process of this installation (a command it is running goes on)."""
    _where()
    answer = resident.control("stop")
    if answer is None:
        typer.echo("no resident process is running for this installation")
        return
    typer.echo(f"resident process {answer['stopping']} stops")


@resident_app.command()
def status(json_out: Annotated[bool, typer.Option("--json", help="Print the status as JSON.")] = False) -> None:
    """Whether a resident process runs for this installation: its pid, commands served, idle time."""
    paths = _where()
    answer = resident.control("status")
    if json_out:
        typer.echo(json.dumps(answer))
        return
    if answer is None:
        why = f" (it failed to start: {paths['failed']})" if paths["failed"].exists() else ""
        typer.echo(f"no resident process is running for this installation{why}")
        return
    typer.echo(f"resident process {answer['pid']}: {answer['served']} commands served, {answer['running']} running, "
               f"idle {answer['idle_s']:g} s of {answer['leaves_after_idle_s']:g} s (key {answer['key']}, "
               f"socket {paths['sock']})")
