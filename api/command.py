"""``excite serve``: run the HTTP service with uvicorn, settings from the ``EXCITE_*``
environment (validated before the server starts). The service's own command: the command line
(:mod:`excite.cli.app`) loads this module by name when it runs ``serve``."""

from __future__ import annotations

from typing import Annotated

import typer

from excite.cli.app import app

# uvicorn's levels (its "trace" is below debug) → logging's numbers
LOG_LEVELS = {"critical": 50, "error": 40, "warning": 30, "info": 20, "debug": 10, "trace": 5}


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Port to listen on.", min=0, max=65535)] = 8000,
    log_level: Annotated[str, typer.Option(help="Log level: " + ", ".join(LOG_LEVELS) + ".")] = "info",
) -> None:
    """Start the HTTP service (OpenAPI at /docs). Settings: EXCITE_DB_PATH, EXCITE_WORKERS,
    EXCITE_SCORE_WORKERS, EXCITE_MAX_BODY_BYTES, EXCITE_MAX_ROUTE_DURATION_S, EXCITE_MAX_SAMPLES,
    EXCITE_REQUEST_TIMEOUT_S, … (see api/settings.py)."""
    from pydantic import ValidationError

    from excite.errors import ExciteError

    if log_level.lower() not in LOG_LEVELS:
        raise ExciteError(f"--log-level: {log_level!r} is not one of {', '.join(LOG_LEVELS)}")
    log_level = log_level.lower()

    from . import Settings, create_app, serving

    try:
        settings = Settings()
    except ValidationError as exc:
        problems = "; ".join(f"EXCITE_{'_'.join(map(str, e['loc'])).upper()}: {e['msg']}"
                             for e in exc.errors())
        # ExciteError: the CLI's one-line message and exit code 1
        raise ExciteError(f"invalid settings: {problems}") from None
    log_service(log_level)
    serving.run(create_app(settings), settings.header_timeout_s, host, port, log_level)


def log_service(level: str) -> None:
    """The service's own messages (re-queued jobs, replaced workers, timeouts) on stderr, at
    uvicorn's level: without a handler only warnings would reach the log, unformatted."""
    import logging

    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    logger = logging.getLogger("excite")
    logger.handlers[:] = [handler]
    logger.setLevel(LOG_LEVELS[level])
    logger.propagate = False
