"""The exception tree of excite, every class of it in this one module.

    Exception
    ├── ExciteError                 base of every error excite raises on purpose
    │   ├── RouteError              a route file or route data is malformed (names file, line, problem)
    │   │   └── BagError            a bag cannot be read as asked (names file, topic, problem)
    │   ├── RigError                a rig config is malformed (names the key)
    │   ├── LimitError              a request for a drive cannot be met within the vehicle's limits
    │   ├── EvaluationError         the information model cannot be evaluated for this input
    │   ├── SceneError              a scene file or scene data is malformed or too large (excite.scene)
    │   ├── OptimizeError           an optimization request is invalid (excite.plan)
    │   ├── ValidateError           a Monte Carlo validation request is invalid (excite.validate)
    │   ├── PlotError               a figure cannot be drawn as asked (excite.score.plots)
    │   ├── ManifestError           a routes manifest is malformed (excite.fleet.batch)
    │   ├── EngineError             the Dask cluster cannot be reached or used (excite.core.engine)
    │   └── DataError               a public recording cannot be fetched or is damaged (excite.io.datasets)
    ├── WorkerDied                  a helper process ended while running a task (excite.core.processes)
    ├── WorkTimeout                 a task did not finish by its deadline (its process was ended)
    ├── FactorisationError          internal: a pivot of the calibrator's banded Cholesky failed
    └── OutOfTime                   internal: a baseline optimizer's time budget ran out

The CLI maps every ExciteError to a one-line message and exit code 1; the HTTP service maps them
to problem+json 4xx responses. The two internal ones never leave the library (the calibrator and
the COBYLA baseline catch their own). Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class ExciteError(Exception):
    """Base of every error excite raises on purpose."""


class RouteError(ExciteError, ValueError):
    """A route file or route data is malformed."""

    def __init__(self, problem: str, *, source: str | None = None, line: int | None = None):
        self.problem = problem
        self.source = source
        self.line = line
        where = ""
        if source is not None:
            where = f"{source}"
            if line is not None:
                where += f", line {line}"
            where += ": "
        super().__init__(where + problem)


class RigError(ExciteError, ValueError):
    """A rig config is malformed; the message names the key."""


class LimitError(ExciteError, ValueError):
    """A drive cannot be produced within the vehicle's limits."""


class EvaluationError(ExciteError, ValueError):
    """The information model cannot be evaluated for this input."""


class SceneError(ExciteError, ValueError):
    """A scene file or scene data is malformed or too large; the message names the file and the field."""

    def __init__(self, problem: str, *, source: str | None = None):
        self.problem = problem
        self.source = source
        super().__init__(f"{source}: {problem}" if source else problem)


class BagError(RouteError):
    """A bag cannot be read as asked: names the file, the topic and the problem."""

    def __init__(self, path: str | Path, problem: str, topic: str | None = None):
        where = f"topic {topic}: " if topic else ""
        super().__init__(where + problem, source=str(path))
        self.topic = topic


class PlotError(ExciteError, ValueError):
    """A figure cannot be drawn as asked (unknown parameter, several drives)."""


class ManifestError(ExciteError, ValueError):
    """A routes manifest is malformed; the message names the file and the key."""


class EngineError(ExciteError):
    """The Dask cluster cannot be reached or used; the message names the address."""


class DataError(ExciteError):
    """A public recording cannot be fetched, or a local copy differs from the catalogue: names the
    file and the URL."""


class ValidateError(ExciteError, ValueError):
    """A simulation, calibration or Monte Carlo validation cannot be run as asked."""


class OptimizeError(ExciteError, ValueError):
    """The optimization cannot be set up (bad settings, a lot too small for the limits)."""


class WorkerDied(Exception):
    """A helper process ended while running a task (killed, out of memory, crashed)."""


class WorkTimeout(Exception):
    """A task did not finish by its deadline; its process was ended."""


class FactorisationError(Exception):
    """A pivot of the banded Cholesky was not positive: ``column`` is the unknown it failed at."""

    def __init__(self, column: int):
        super().__init__(column)
        self.column = column


class OutOfTime(Exception):
    """A baseline optimizer's time budget ran out (caught by :func:`excite.plan.baselines.cobyla`)."""
