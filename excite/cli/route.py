"""``excite route ...``: inspect route files."""

from __future__ import annotations

import typer

from . import app

route_app = typer.Typer(no_args_is_help=True, help="Inspect route files.")
app.add_typer(route_app, name="route")
