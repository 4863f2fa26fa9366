"""The exception tree of excite.

    ExciteError                 base of every error excite raises on purpose
    ├── RouteError              a route file or route data is malformed (names file, line, problem)
    │   └── BagError            a bag cannot be read as asked (excite.bags: names file, topic, problem)
    ├── RigError                a rig config is malformed (names the key)
    ├── LimitError              a request for a drive cannot be met within the vehicle's limits
    ├── EvaluationError         the information model cannot be evaluated for this input
    ├── OptimizeError           an optimization request is invalid (excite.optimize)
    └── ValidateError           a Monte Carlo validation request is invalid (excite.validate)

The CLI maps every ExciteError to a one-line message and exit code 1; the HTTP service maps them
to problem+json 4xx responses. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


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
