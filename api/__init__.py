"""The excite HTTP service: a thin FastAPI layer over the :mod:`excite` library.

``create_app(Settings())`` builds the app; ``excite serve`` runs it with uvicorn.
"""

from .app import create_app
from .settings import Settings

__all__ = ["Settings", "create_app"]
