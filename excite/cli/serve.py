"""``excite serve``: run the HTTP service with uvicorn, settings from the ``EXCITE_*``
environment (validated before the server starts)."""

from __future__ import annotations

from typing import Annotated

import typer

from . import app


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Port to listen on.", min=0, max=65535)] = 8000,
    log_level: Annotated[str, typer.Option(help="Log level (critical, error, warning, info, debug).")] = "info",
) -> None:
    """Start the HTTP service (OpenAPI at /docs). Settings: EXCITE_DB_PATH, EXCITE_WORKERS,
    EXCITE_SCORE_WORKERS, EXCITE_MAX_BODY_BYTES, EXCITE_MAX_ROUTE_DURATION_S, EXCITE_MAX_SAMPLES,
    EXCITE_REQUEST_TIMEOUT_S, … (see api/settings.py)."""
    import uvicorn
    from pydantic import ValidationError

    from api import Settings, create_app

    from ..errors import ExciteError

    try:
        settings = Settings()
    except ValidationError as exc:
        problems = "; ".join(f"EXCITE_{'_'.join(map(str, e['loc'])).upper()}: {e['msg']}"
                             for e in exc.errors())
        # ExciteError: the CLI's one-line message and exit code 1
        raise ExciteError(f"invalid settings: {problems}") from None
    log_service(log_level)
    # one server process: the job store is shared, the dispatcher must be alone
    from api.routers.live import MAX_MESSAGE_BYTES

    uvicorn.run(create_app(settings), host=host, port=port, log_level=log_level,
                timeout_graceful_shutdown=10, ws_max_size=MAX_MESSAGE_BYTES)


def log_service(level: str) -> None:
    """The service's own messages (re-queued jobs, replaced workers, timeouts) on stderr, at
    uvicorn's level: without a handler only warnings would reach the log, unformatted."""
    import logging

    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    logger = logging.getLogger("excite")
    logger.handlers[:] = [handler]
    logger.setLevel(getattr(logging, level.upper(), logging.INFO))
    logger.propagate = False
