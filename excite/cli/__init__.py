"""The ``excite`` command line: loads inputs, calls the library, prints and saves.

Known failures (every :class:`~excite.errors.ExciteError`, unreadable files) end in a one-line
message on stderr and exit code 1; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import sys

import typer

from ..errors import ExciteError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Calibration excitation planner: how well does a drive determine every "
                       "sensor calibration parameter?")


def _register() -> None:
    # Sub-command modules register themselves on `app` when imported.
    from . import batch, optimize, route, score, serve, validate  # noqa: F401


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
    _register()
    try:
        # without standalone mode click returns a command's exit code instead of exiting
        rc = app(args=argv, standalone_mode=False)
        if isinstance(rc, int):
            return rc
    except ExciteError as exc:
        print(f"excite: error: {exc}", file=sys.stderr)
        return 1
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"excite: error: {exc.filename}: {exc.strerror}", file=sys.stderr)
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


if __name__ == "__main__":
    sys.exit(main())
