"""``excite data list | fetch | check``: the public recordings the examples use (logic in
:mod:`excite.io.datasets`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from .app import app

data_app = typer.Typer(no_args_is_help=True, help="The public recordings the examples and tests use: "
                                                  "list them, fetch them, check a local copy.")
app.add_typer(data_app, name="data")

Folder = Annotated[Optional[Path], typer.Option(
    "--dir", help="Data folder (default: $EXCITE_DATA_DIR, else ../shared/data).")]


def _selected(names: list[str], every: bool) -> list[str]:
    from ..errors import DataError
    from ..io import datasets

    if every:
        return list(datasets.DATASETS)
    if not names:
        raise DataError("name a dataset (excite data list shows them) or give --all")
    for n in names:
        datasets.dataset(n)
    return names


@data_app.command("list")
def list_() -> None:
    """Every dataset: name, size, what it is, its source and licence."""
    from ..io import datasets

    for d in datasets.DATASETS.values():
        typer.echo(f"{d.name:26s} {d.size / 2**20:6.1f} MiB  {d.description}")
        typer.echo(f"{'':26s} {'':10s}source: {d.source}; licence: {d.licence}")


@data_app.command()
def fetch(names: Annotated[Optional[list[str]], typer.Argument(help="Dataset names.")] = None,
          every: Annotated[bool, typer.Option("--all", help="Every dataset.")] = False,
          folder: Folder = None) -> None:
    """Download the named datasets' missing or damaged files and check each against its SHA-256."""
    from ..io import datasets

    target = folder if folder is not None else datasets.default_folder()
    for name in _selected(names or [], every):
        got = datasets.fetch(name, target, progress=lambda f: typer.echo(f"downloading {f.path} ({f.size / 2**20:.1f} MiB)", err=True))
        typer.echo(f"{name}: {len(got)} file(s) downloaded, {len(datasets.dataset(name).files)} checked in {target}")


@data_app.command()
def check(names: Annotated[Optional[list[str]], typer.Argument(help="Dataset names (default: every one).")] = None,
          folder: Folder = None) -> None:
    """Check local copies against the catalogue's sizes and SHA-256 (no network); exit 1 on a problem."""
    from ..io import datasets

    target = folder if folder is not None else datasets.default_folder()
    bad = 0
    for name in names or list(datasets.DATASETS):
        problems = datasets.check(name, target)
        typer.echo(f"{name}: " + ("ok" if not problems else "; ".join(problems)))
        bad += bool(problems)
    if bad:
        raise typer.Exit(1)
