"""The ``excite`` command line: loads inputs, calls the library, prints and saves.

Known failures (every :class:`~excite.errors.ExciteError`, unreadable or unwritable files) end in
a one-line message on stderr and exit code 1; anything else is a bug and keeps its traceback.

A command imports only what it uses: ``excite score`` never loads the optimizer, ``excite
--help`` neither numpy nor scipy. Help text is plain (no rich markup: units such as ``[s]``
are text), and output to a pipe is not wrapped at 80 columns.
"""

from __future__ import annotations

import gc
import importlib
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any, Optional

import typer

from ..errors import ExciteError

# command → the module that registers it on `app` (``serve`` is the service's own: the service sits
# above the command line and adds its command to it)
COMMANDS = {c: f"excite.cli.{m}" for c, m in {
    "batch": "batch", "data": "data", "live": "live", "mine": "mine", "optimize": "optimize", "route": "route",
    "rig": "rig_import", "scene": "scene", "score": "score", "validate": "validate"}.items()}
COMMANDS["serve"] = "api.command"

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None,
                  help="Calibration excitation planner: how well does a drive determine every "
                       "sensor calibration parameter?")

PIPE_WIDTH = 100  # columns of output to a pipe or file (a terminal's own width otherwise)


def _version(value: bool) -> None:
    if value:
        from .. import __version__

        typer.echo(f"excite {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: Annotated[Optional[bool], typer.Option(
        "--version", callback=_version, is_eager=True, help="Print the version and exit.")] = None) -> None:
    pass


def console(stderr: bool = False) -> Any:
    """A rich console for the commands' tables: the terminal's width, or :data:`PIPE_WIDTH`
    when the output is piped (rich would wrap at 80). Tables wrap their cells between words and
    never cut one: each column is at least as wide as its longest word (:func:`fit_words`)."""
    from rich.console import Console

    class WordConsole(Console):
        def print(self, *objects: Any, **kwargs: Any) -> None:
            for obj in objects:
                fit_words(obj, self.width)
            super().print(*objects, **kwargs)

    stream = sys.stderr if stderr else sys.stdout
    piped = not stream.isatty() and "COLUMNS" not in os.environ
    return WordConsole(stderr=stderr, width=PIPE_WIDTH if piped else None)


def fit_words(table: Any, width: int) -> None:
    """Widths for the columns of a rich ``table`` that fit ``width`` and wrap cells between words
    instead of cutting one: each column at least as wide as its longest word (header and cells),
    the room left shared in proportion to what each needs beyond that. Where the longest words
    together are wider than the room, the widest columns give way first and fold what must be
    folded (never cropping it)."""
    from rich.table import Table
    from rich.text import Text

    if not isinstance(table, Table) or not table.columns:
        return
    lo, hi = [], []
    for col in table.columns:
        words, lines = [1], [1]
        for cell in [col.header, *col.cells]:
            plain = cell.plain if isinstance(cell, Text) else Text.from_markup(cell).plain if isinstance(cell, str) else ""
            words += [len(w) for w in plain.split()]
            lines += [len(line) for line in plain.splitlines()]
        lo.append(max(words))
        hi.append(max(max(lines), max(words)))
    n = len(lo)
    pad = table.padding[1] + table.padding[3]
    room = width - n * pad - ((n + 1) if table.box is not None and table.show_edge else max(n - 1, 0))
    if sum(hi) <= room:
        return  # rich lays it out whole
    while sum(lo) > room and max(lo) > 8:
        k = lo.index(max(lo))
        lo[k] = max(8, lo[k] - (sum(lo) - room))
    spare = max(room - sum(lo), 0)
    need = [h - w for h, w in zip(hi, lo)]
    total = sum(need) or 1
    widths = [w + int(spare * d / total) for w, d in zip(lo, need)]
    for col, w in zip(table.columns, widths):
        col.width = w
        col.overflow = "fold"


def command_of(argv: list[str]) -> str | None:
    """The command word of ``excite`` arguments (the root takes no option with a value)."""
    words = [a for a in argv if not a.startswith("-")]
    return words[0] if words else None


def register(argv: list[str]) -> None:
    """Import the module of the command being run (all of them for the overview help)."""
    command = command_of(argv)
    wanted = [COMMANDS[command]] if command in COMMANDS else [COMMANDS[c] for c in sorted(COMMANDS)]
    with imports():
        for module in wanted:
            importlib.import_module(module)


# whether this process is the command's alone (the console script, :func:`run`), not a program
# that calls :func:`main`
_own_process = False


@contextmanager
def imports() -> Iterator[None]:
    """Import what a command needs without the cyclic garbage collector walking it as it arrives.

    numpy, scipy, pydantic's models and excite's own modules are ~100 000 objects, none of them
    garbage; while they arrive the collector passes over the whole growing heap again and again
    (~50 ms of the CPU time of a fresh ``excite score``). In the command's own process (:func:`run`)
    the collector pauses while they are imported, and what they made is then left out of its
    passes for good (:func:`gc.freeze`: it lives as long as the process); it runs as before after.
    A program that calls :func:`main` keeps its collector as it is."""
    if not _own_process:
        yield
        return
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _click_exceptions() -> tuple[type[Exception], ...]:
    # typer ≥ 0.26 vendors click as typer._click: its usage errors are not click's
    import click

    types: list[type[Exception]] = [click.ClickException]
    try:
        from typer._click.exceptions import ClickException as Vendored
    except ImportError:
        pass
    else:
        types.append(Vendored)
    return tuple(types)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    register(argv)
    try:
        # without standalone mode click returns a command's exit code instead of exiting
        rc = app(args=argv, standalone_mode=False, prog_name="excite")
        if isinstance(rc, int):
            return rc
    except ExciteError as exc:
        print(f"excite: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a file the user named cannot be read or written
        where = exc.filename if exc.filename is not None else ""
        print(f"excite: error: {where}{': ' if where else ''}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        print("excite: aborted", file=sys.stderr)
        return 130
    except Exception as exc:  # click usage errors carry their own exit code
        if isinstance(exc, _click_exceptions()):
            exc.show()
            return exc.exit_code
        raise
    return 0


def run() -> None:
    """The ``excite`` script and ``python -m excite.cli``: :func:`main` in a process of its own
    (see :func:`imports`), then :func:`leave`."""
    global _own_process
    _own_process = True
    leave(main())


def leave(rc: int) -> None:
    """End the process with exit code ``rc``.

    What the command imported (numpy, scipy, pydantic's models: ~100 000 objects) lives until
    the process ends; at exit the interpreter's cyclic garbage collector would walk all of it
    again while tearing the modules down (~0.3 s of a cold ``excite score``; see
    ``benchmarks/bench_cli.py``). :func:`gc.freeze` leaves those objects out of that walk; they are
    still released, atexit handlers run and streams are flushed as usual."""
    gc.freeze()
    sys.exit(rc)


if __name__ == "__main__":
    run()
